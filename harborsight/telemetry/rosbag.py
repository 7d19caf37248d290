"""ROS 1 and ROS 2 bags as a drone log and as frames: ``telemetry show BAG``, ``telemetry video
BAG``, ``telemetry bag BAG --out FLIGHT`` (then ``harborsight run FLIGHT``).

Topics read (chosen by option, else found by type and name, :func:`choose_topics`):

* position: ``sensor_msgs/NavSatFix`` (samples with ``status.status`` below 0, "no fix", are
  skipped). Its ``altitude`` is above the WGS-84 ellipsoid (the message's definition); a
  ``std_msgs/Float64`` or ``Float32`` topic named like ``rel_alt`` (MAVROS'
  ``global_position/rel_alt``: above the take-off point) is used instead where there is one;
* accuracy: the fix's ``position_covariance`` where its type is 1-3 (ENU, m²: per-axis sigma
  ``sqrt((c_ee + c_nn) / 2)``, height ``sqrt(c_uu)``), else the fix status's class (a fix:
  standalone; SBAS or GBAS: DGPS, since drivers report RTK as either);
* attitude: the orientation of ``sensor_msgs/Imu``, ``geometry_msgs/QuaternionStamped`` or
  ``PoseStamped``. ROS's convention (REP 103) is a world frame east-north-up and a body frame
  forward-left-up (MAVROS publishes so); ``attitude_frame="ned"`` takes north-east-down and
  forward-right-down (PX4's and DJI's own). Turned into ``harborsight.frame/1``'s NED ZYX
  Euler angles with ``R_NED<-FRD = M · R_ENU<-FLU · F`` (M swaps east and north and flips up,
  F flips y and z). A topic named like ``gimbal`` or ``camera`` is the camera's attitude (its
  body x the optical axis); any other the airframe's, for a stabilised or rigid mount;
* images: ``sensor_msgs/CompressedImage`` (written as the JPEG or PNG it holds) or ``Image``
  (``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8``, ``mono16``; written as PNG);
* intrinsics: the first ``sensor_msgs/CameraInfo`` (K, and D for ``plumb_bob`` or
  ``rational_polynomial``; other models need ``--camera``), or its P with no distortion when
  the image topic is image_proc's rectified ``image_rect...``.

Time: each message's ``header.stamp`` (the bag's receive time where the stamp is zero), Unix
time: UTC when the recording computer's clock was synchronised (NTP, GPS). A track's ``t_s`` is
seconds since its first fix.
"""

from __future__ import annotations

import io
import math
import re
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from harborsight.errors import HarborsightError, InputError
from harborsight.files import strict_json
from harborsight.telemetry.accuracy import per_axis_from_class_m, usable
from harborsight.telemetry.rosbag_io import BagMessage, BagReader, open_bag
from harborsight.telemetry.track import Track, interpolate_source, utc_from_epoch_s

IMAGE_TYPES = ("sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image")
FIX_TYPES = ("sensor_msgs/msg/NavSatFix",)
ATTITUDE_TYPES = ("sensor_msgs/msg/Imu", "geometry_msgs/msg/QuaternionStamped",
                  "geometry_msgs/msg/PoseStamped")
CAMERA_INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
HEIGHT_TYPES = ("std_msgs/msg/Float64", "std_msgs/msg/Float32")
ATTITUDE_FRAMES = ("enu", "ned")
ATTITUDE_OF = ("auto", "gimbal", "vehicle")
_GIMBAL_NAME = re.compile(r"gimbal|camera|mount", re.IGNORECASE)
_REL_ALT_NAME = re.compile(r"rel(ative)?_?alt", re.IGNORECASE)
#: NavSatStatus.status -> GPS_CLASSES name (0 fix, 1 SBAS, 2 GBAS)
FIX_STATUS_CLASSES = {0: "standalone", 1: "dgps", 2: "dgps"}
#: ENU <-> NED (swap east and north, flip up) and FLU <-> FRD (flip y and z)
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])


@dataclass
class BagTopics:
    image: str | None = None
    fix: str | None = None
    attitude: str | None = None
    attitude_of: str | None = None         # "gimbal" or "vehicle"
    camera_info: str | None = None
    rel_alt: str | None = None
    others: dict[str, list[str]] = field(default_factory=dict)   # role -> topics not chosen


def choose_topics(reader: BagReader, *, image: str | None = None, fix: str | None = None,
                  attitude: str | None = None, camera_info: str | None = None,
                  rel_alt: str | None = None, attitude_of: str = "auto") -> BagTopics:
    """The topic of each role: the one given (it must exist with a type of that role:
    :class:`InputError` naming the option otherwise), else the bag's topic of that type with
    the most messages, preferring a name that says the role (``gimbal``/``camera`` for the
    camera's attitude, ``rel_alt`` for the height)."""
    if attitude_of not in ATTITUDE_OF:
        raise InputError(None, "--attitude-of", f"{attitude_of!r}: expected one of "
                         + ", ".join(ATTITUDE_OF))
    chosen = BagTopics()

    def pick(role: str, given: str | None, types: tuple[str, ...], prefer=None) -> str | None:
        candidates = [t for t in reader.topics.values() if t.msgtype in types]
        if given is not None:
            info = reader.topics.get(given)
            if info is None or info.msgtype not in types:
                what = "not in the bag" if info is None else f"of type {info.msgtype}"
                raise InputError(reader.path, f"--{role}-topic", f"{given} is {what}; "
                                 f"topics of {' or '.join(types)}: "
                                 + (", ".join(t.name for t in candidates) or "none"))
            return given
        if not candidates:
            return None
        ranked = sorted(candidates, key=lambda t: (bool(prefer and prefer.search(t.name)), t.count),
                        reverse=True)
        chosen.others[role] = [t.name for t in ranked[1:]]
        return ranked[0].name

    chosen.image = pick("image", image, IMAGE_TYPES)
    chosen.fix = pick("fix", fix, FIX_TYPES)
    prefer_gimbal = None if attitude_of == "vehicle" else _GIMBAL_NAME
    chosen.attitude = pick("attitude", attitude, ATTITUDE_TYPES, prefer_gimbal)
    if chosen.attitude is not None:
        chosen.attitude_of = (attitude_of if attitude_of != "auto" else
                              "gimbal" if _GIMBAL_NAME.search(chosen.attitude) else "vehicle")
    chosen.camera_info = pick("camera-info", camera_info, CAMERA_INFO_TYPES)
    if rel_alt is not None:
        chosen.rel_alt = pick("rel-alt", rel_alt, HEIGHT_TYPES)
    else:
        heights = [t for t in reader.topics.values()
                   if t.msgtype in HEIGHT_TYPES and _REL_ALT_NAME.search(t.name)]
        chosen.rel_alt = max(heights, key=lambda t: t.count).name if heights else None
    return chosen


def stamp_s(message: BagMessage) -> float:
    """The message's header stamp in Unix seconds, else its receive time."""
    header = getattr(message.message, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is not None:
        seconds = float(stamp.sec) + float(getattr(stamp, "nanosec", 0)) * 1e-9
        if seconds > 0:
            return seconds
    return message.log_time_ns * 1e-9


def quaternion_of(message: object) -> tuple[float, float, float, float] | None:
    """The (x, y, z, w) orientation of an Imu, QuaternionStamped or PoseStamped message; None
    for an Imu that says it has none (covariance[0] = -1) or a quaternion of no length."""
    if hasattr(message, "orientation_covariance"):
        if len(message.orientation_covariance) and message.orientation_covariance[0] == -1:
            return None
        q = message.orientation
    elif hasattr(message, "quaternion"):
        q = message.quaternion
    elif hasattr(message, "pose"):
        q = message.pose.orientation
    else:
        return None
    values = (float(q.x), float(q.y), float(q.z), float(q.w))
    norm = math.sqrt(sum(v * v for v in values)) if all(map(math.isfinite, values)) else 0.0
    return None if not 0.5 < norm < 2.0 else tuple(v / norm for v in values)


def ned_euler_deg(quaternions: np.ndarray, frame: str) -> np.ndarray:
    """Yaw, pitch, roll (NED ZYX Euler, degrees) of (x, y, z, w) orientations given in the
    ``frame`` convention (module docstring)."""
    rotations = Rotation.from_quat(quaternions).as_matrix()
    if frame == "enu":
        rotations = ENU_TO_NED @ rotations @ FRD_TO_FLU
    with warnings.catch_warnings():          # gimbal lock at -90 deg pitch: yaw takes the roll
        warnings.simplefilter("ignore", UserWarning)
        return Rotation.from_matrix(rotations).as_euler("ZYX", degrees=True)


def read_bag_track(path: str | Path, *, reader: BagReader | None = None,
                   topics: BagTopics | None = None, attitude_frame: str = "enu") -> Track:
    """The drone's track from a bag's fix, height and attitude topics (module docstring)."""
    if attitude_frame not in ATTITUDE_FRAMES:
        raise InputError(None, "--attitude-frame", f"{attitude_frame!r}: expected enu or ned")
    reader = reader or open_bag(path)
    topics = topics or choose_topics(reader)
    if topics.fix is None:
        raise InputError(reader.path, "NavSatFix", "no sensor_msgs/NavSatFix topic: the bag "
                         "holds no position (topics: " + ", ".join(sorted(reader.topics)) + ")")
    wanted = {t for t in (topics.fix, topics.attitude, topics.rel_alt) if t}
    fixes, heights, attitudes = [], [], []
    no_fix = 0
    for message in reader.messages(wanted):
        body = message.message
        if message.topic == topics.fix:
            status = int(getattr(body.status, "status", 0))
            lat, lon, alt = float(body.latitude), float(body.longitude), float(body.altitude)
            if status < 0 or not (abs(lat) <= 90 and abs(lon) <= 180) or (lat, lon) == (0, 0):
                no_fix += 1
                continue
            covariance = np.asarray(body.position_covariance, float)
            kind = int(body.position_covariance_type)
            fixes.append((stamp_s(message), lat, lon, alt, status, kind, covariance))
        elif message.topic == topics.rel_alt:
            heights.append((stamp_s(message), float(body.data)))
        elif message.topic == topics.attitude and (q := quaternion_of(body)) is not None:
            attitudes.append((stamp_s(message), *q))
    notes = list(reader.notes)
    if reader.undecodable:
        notes.append(f"{reader.undecodable} message(s) that do not deserialise skipped")
    if no_fix:
        notes.append(f"{no_fix} fix(es) without a position (status 'no fix') skipped")
    if not fixes:
        raise InputError(reader.path, topics.fix, "no fix with a position")
    fixes.sort(key=lambda f: f[0])
    t0 = fixes[0][0]
    t_s = np.array([f[0] - t0 for f in fixes])
    lat = np.array([f[1] for f in fixes])
    lon = np.array([f[2] for f in fixes])
    if topics.rel_alt and heights:
        heights.sort()
        h_t = np.array([h[0] - t0 for h in heights])
        alt, widest_s = interpolate_source(t_s, h_t, np.array([h[1] for h in heights]))
        if widest_s is not None:
            notes.append(f"{int(np.isnan(alt).sum())} fix(es) without a height: outside "
                         f"{topics.rel_alt}'s span or in its gaps (up to {widest_s:.1f} s); "
                         "frames there are skipped unless --max-gap-s bridges them")
        reference = f"height above the take-off point ({topics.rel_alt})"
    else:
        alt = np.array([f[3] for f in fixes])
        reference = f"above the WGS-84 ellipsoid (NavSatFix altitude, {topics.fix})"
    sigma, alt_sigma = _fix_sigmas(fixes, notes)
    yaw = pitch = roll = attitude_t = None
    if attitudes:
        attitudes.sort()
        attitude_t = np.array([a[0] - t0 for a in attitudes])
        euler = ned_euler_deg(np.array([a[1:] for a in attitudes]), attitude_frame)
        yaw, pitch, roll = euler[:, 0], euler[:, 1], euler[:, 2]
        notes.append(f"attitude of the {'camera (gimbal)' if topics.attitude_of == 'gimbal' else 'airframe'}"
                     f" from {topics.attitude} ({attitude_frame.upper()} convention)")
    return Track(
        source=reader.path, kind="rosbag", t_s=t_s, lat_deg=lat, lon_deg=lon, alt_m=alt,
        alt_reference=reference, yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll,
        attitude_of=topics.attitude_of if attitudes else None, attitude_t_s=attitude_t,
        position_sigma_m=sigma, alt_sigma_m=alt_sigma if topics.rel_alt is None else None,
        utc_start=utc_from_epoch_s(t0), clock="ROS header stamps (Unix time: UTC when the "
        "recording computer's clock was synchronised)", notes=notes)


def _fix_sigmas(fixes: list, notes: list[str]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Per-axis horizontal and vertical sigmas (m) from each fix's covariance, else its
    status class (module docstring); None where no fix gives one."""
    horizontal = np.full(len(fixes), np.nan)
    vertical = np.full(len(fixes), np.nan)
    from_covariance = 0
    for i, (_, _, _, _, status, kind, covariance) in enumerate(fixes):
        if kind in (1, 2, 3) and covariance.shape == (9,):
            horizontal[i] = usable(math.sqrt(max((covariance[0] + covariance[4]) / 2.0, 0.0)))[0]
            vertical[i] = usable(math.sqrt(max(covariance[8], 0.0)))[0]
            from_covariance += np.isfinite(horizontal[i])
        if not np.isfinite(horizontal[i]):
            horizontal[i] = per_axis_from_class_m([status], [np.nan], FIX_STATUS_CLASSES)[0]
    statuses = [f[4] for f in fixes]
    names = {0: "fix", 1: "SBAS fix", 2: "GBAS fix"}
    notes.append(f"accuracy: {from_covariance} of {len(fixes)} fixes from their covariance, the "
                 "others from the fix status (" + ", ".join(
                     f"{names.get(s, f'status {s}')} {statuses.count(s)}" for s in sorted(set(statuses)))
                 + ")")
    return (horizontal if np.isfinite(horizontal).any() else None,
            vertical if np.isfinite(vertical).any() else None)


def is_rectified_topic(topic: str) -> bool:
    """An image topic that image_proc has rectified (``image_rect``, ``image_rect_color``,
    and their ``compressed`` transports): its pixels follow CameraInfo's P, not K and D."""
    names = [part for part in topic.strip("/").split("/") if part]
    while names and names[-1] in ("compressed", "compressedDepth", "theora"):
        names.pop()
    return bool(names) and names[-1].startswith("image_rect")


def camera_from_info(message: object, rectified: bool = False) -> dict:
    """A frame/1 camera block from a CameraInfo message; :class:`InputError` for a model
    other than plumb_bob / rational_polynomial or a K without a focal length. For a
    ``rectified`` image (:func:`is_rectified_topic`) the intrinsics are P's left 3x3 and no
    distortion, as ROS defines them: K and D describe the raw image, and applying D to an
    image already undistorted bends it a second time."""
    k = [float(v) for v in message.k] if hasattr(message, "k") else [float(v) for v in message.K]
    d = [float(v) for v in (message.d if hasattr(message, "d") else message.D)]
    if rectified:
        p = [float(v) for v in (message.p if hasattr(message, "p") else message.P)]
        # (p is P, row-major 3x4; its left 3x3 is the rectified image's K)
        if len(p) != 12 or not (p[0] > 0 and p[5] > 0) or not all(map(math.isfinite, p)):
            raise InputError(None, "CameraInfo", "the image topic is rectified but P has no "
                             "focal length: give --camera")
        # the raw camera's model does not matter: image_proc rectifies a fisheye to P too
        return {"width": int(message.width), "height": int(message.height), "fx": p[0],
                "fy": p[5], "cx": p[2], "cy": p[6], "distortion": [0.0] * 5}
    model = str(message.distortion_model or "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial", ""):
        raise InputError(None, "CameraInfo", f"distortion model {model!r}: give --camera with "
                         "an OpenCV calibration instead")
    if not (k[0] > 0 and k[4] > 0) or not all(map(math.isfinite, k + d)):
        raise InputError(None, "CameraInfo", "K has no focal length: give --camera")
    return {"width": int(message.width), "height": int(message.height), "fx": k[0], "fy": k[4],
            "cx": k[2], "cy": k[5], "distortion": (d + [0.0] * 5)[:max(5, min(len(d), 8))]}


_RAW_ENCODINGS = {"rgb8": (3, np.uint8, "rgb"), "bgr8": (3, np.uint8, "bgr"),
                  "rgba8": (4, np.uint8, "rgb"), "bgra8": (4, np.uint8, "bgr"),
                  "mono8": (1, np.uint8, "mono"), "mono16": (1, np.uint16, "mono")}


def image_bytes(message: object) -> tuple[bytes, str]:
    """An image message as file bytes and their suffix: a CompressedImage's own JPEG or PNG,
    a raw Image as PNG (BGR, 8 bit). ValueError for an encoding not handled."""
    import cv2

    if hasattr(message, "format"):             # CompressedImage
        data = bytes(message.data)
        if data[:3] == b"\xff\xd8\xff":
            return data, ".jpg"
        if data[:8] == b"\x89PNG\r\n\x1a\n":
            return data, ".png"
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"compressed image of format {message.format!r} does not decode")
    else:
        encoding = str(message.encoding).lower()
        if encoding not in _RAW_ENCODINGS:
            raise ValueError(f"image encoding {encoding!r} is not one of "
                             + ", ".join(_RAW_ENCODINGS))
        channels, dtype, order = _RAW_ENCODINGS[encoding]
        height, width, step = int(message.height), int(message.width), int(message.step)
        raw = np.frombuffer(bytes(message.data), np.uint8)
        if step < width * channels * np.dtype(dtype).itemsize or raw.size < step * height:
            raise ValueError("image data shorter than its height times its step")
        rows = raw[:step * height].reshape(height, step)[:, :width * channels * np.dtype(dtype).itemsize]
        pixels = rows.copy().view(dtype.newbyteorder(">" if message.is_bigendian else "<")
                                  if dtype != np.uint8 else dtype).reshape(height, width, channels)
        if dtype == np.uint16:
            pixels = (pixels.astype(np.float64) / 257.0).round().astype(np.uint8)
        if order == "rgb":
            image = cv2.cvtColor(pixels[:, :, :3], cv2.COLOR_RGB2BGR)
        elif order == "bgr":
            image = np.ascontiguousarray(pixels[:, :, :3])
        else:
            image = cv2.cvtColor(pixels[:, :, 0], cv2.COLOR_GRAY2BGR)
    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("the image could not be written as PNG")
    return encoded.tobytes(), ".png"


def _image_size(data: bytes) -> tuple[int, int] | None:
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:
            return image.size
    except Exception:
        return None


@dataclass
class BagFrames:
    written: int = 0
    images: int = 0
    skipped: list[tuple[int, str]] = field(default_factory=list)    # (image index, reason)
    camera_from: str = ""


def write_bag_frames(
    reader: BagReader, topics: BagTopics, drone: Track, vessel: Track, out_dir: Path, *,
    water_level_m: float, mount=None, camera: dict | None = None, vessel_offset_s: float = 0.0,
    max_gap_s: float = 1.0, every: int = 1, on_image: Callable[[int], None] | None = None,
) -> BagFrames:
    """The bag's images as a flight folder ``out_dir/images/NNNNNN.jpg|png`` with
    ``out_dir/frames/NNNNNN.json`` (``harborsight run out_dir``): the drone and the vessel
    sampled at each image's stamp. Every ``every``-th image; an image that cannot be a frame
    is listed with its reason."""
    from harborsight.telemetry.metadata import CameraMount, frames_at_times

    if topics.image is None:
        raise InputError(reader.path, "--image-topic", "no sensor_msgs/Image or CompressedImage "
                         "topic in the bag")
    mount = mount or CameraMount()
    result = BagFrames()
    if camera is None:
        if topics.camera_info is None:
            raise InputError(reader.path, "--camera", "no sensor_msgs/CameraInfo topic: give "
                             "--camera (a calibration file)")
        info = next(reader.messages({topics.camera_info}), None)
        if info is None:
            raise InputError(reader.path, topics.camera_info, "no readable CameraInfo message")
        try:
            rectified = is_rectified_topic(topics.image)
            camera = camera_from_info(info.message, rectified)
        except InputError as exc:
            raise InputError(reader.path, topics.camera_info, exc.message) from None
        result.camera_from = (f"CameraInfo ({topics.camera_info})"
                              + (", P (the image topic is rectified)" if rectified else ""))
    else:
        result.camera_from = "given (--camera)"
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    (out_dir / "frames").mkdir(parents=True, exist_ok=True)
    t0 = drone.utc_start.timestamp()
    for index, message in enumerate(reader.messages({topics.image})):
        if index % every:
            continue
        result.images += 1
        try:
            data, suffix = image_bytes(message.message)
            size = _image_size(data)
            if size != (camera["width"], camera["height"]):
                raise ValueError(f"image is {size[0]}x{size[1]} px, the camera "
                                 f"{camera['width']}x{camera['height']}" if size else
                                 "image does not decode")
            when = utc_from_epoch_s(stamp_s(message))
            vessel_t = np.array([vessel.seconds_of(when) + vessel_offset_s])
            frames = frames_at_times(drone, vessel, camera, np.array([when.timestamp() - t0]),
                                     vessel_t, [when], water_level_m=water_level_m, mount=mount,
                                     max_gap_s=max_gap_s, indices=[index])
            if not frames.frames:
                raise ValueError(frames.skipped[0][1])
            name = f"{index:06d}"
            frame = {"schema": frames.frames[0]["schema"], "image": name + suffix,
                     **frames.frames[0]}
            frame["telemetry"]["image_topic"] = topics.image
            (out_dir / "images" / (name + suffix)).write_bytes(data)
            (out_dir / "frames" / f"{name}.json").write_text(strict_json(frame, indent=1) + "\n")
            result.written += 1
        except (ValueError, HarborsightError) as exc:
            result.skipped.append((index, str(exc)))
        if on_image is not None:
            on_image(index)
    return result
