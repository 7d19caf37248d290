"""``harborsight.frame/1`` metadata: parsing, validation and the posed frame geometry.

The world frame of one frame is the local ENU plane whose origin is the vessel's GPS
position at the water level: the vessel antenna sits at ``(0, 0)`` and the water plane is
``z = 0``. Heights above water are ``alt_m - water_level_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from harborsight.errors import InputError, brief
from harborsight.geometry.calibration_files import load_camera_calibration
from harborsight.geometry.camera import MAX_IMAGE_SIDE_PX, Camera, CameraIntrinsics
from harborsight.geometry.geodesy import GeoOrigin, geodetic_to_enu
from harborsight.geometry.rotations import enu_from_vessel_rotation, world_from_camera_rotation
from harborsight.geometry.sensor_sigmas import FRAME_SIGMA_FIELDS
from harborsight.text_formats import parse_json_text

FRAME_SCHEMA = "harborsight.frame/1"


@dataclass(frozen=True)
class FrameMetadata:
    """One frame's metadata (angles in degrees, as in the file)."""

    image: str
    camera: CameraIntrinsics
    uav_lat_deg: float
    uav_lon_deg: float
    uav_alt_m: float
    yaw_deg: float
    pitch_deg: float
    roll_deg: float
    vessel_lat_deg: float
    vessel_lon_deg: float
    vessel_heading_deg: float
    water_level_m: float = 0.0
    timestamp: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    source: str | None = None
    #: the sensors' own one-sigma figures the file carries (FRAME_SIGMA_FIELDS), by
    #: SensorSigmas name; positions per axis
    sensor_sigmas: dict[str, float] = field(default_factory=dict)
    #: ground velocities (east, north) in m/s, when the file gives them
    uav_velocity_en_mps: tuple[float, float] | None = None
    vessel_velocity_en_mps: tuple[float, float] | None = None
    #: one sigma (m/s, per axis) of the vessel's velocity, its rate of turn (deg/s, the
    #: heading's: clockwise) and that rate's sigma, when the file gives them
    #: (``vessel.velocity_sigma_mps``, ``vessel.yaw_rate_deg_s``,
    #: ``vessel.yaw_rate_sigma_deg_s``): the vessel's own motion of each clearance
    #: (:mod:`harborsight.clearance.own_motion`)
    vessel_velocity_sigma_mps: float | None = None
    vessel_yaw_rate_deg_s: float | None = None
    vessel_yaw_rate_sigma_deg_s: float | None = None
    #: the sun (``sun`` block: elevation above the horizon, azimuth clockwise from north),
    #: when the file gives it; else the geometry computes it from ``timestamp``
    sun_elevation_deg: float | None = None
    sun_azimuth_deg: float | None = None
    #: how long (s) the vessel's pose was carried forward by its speed and course from its
    #: last position report (``vessel.dead_reckoned_s``: AIS between reports), when it was
    vessel_dead_reckoned_s: float | None = None

    @property
    def height_above_water_m(self) -> float:
        return self.uav_alt_m - self.water_level_m

    def to_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {
            "schema": FRAME_SCHEMA,
            "image": self.image,
            "camera": self.camera.to_dict(),
            "uav": {"lat": self.uav_lat_deg, "lon": self.uav_lon_deg, "alt_m": self.uav_alt_m},
            "camera_attitude": {
                "yaw_deg": self.yaw_deg, "pitch_deg": self.pitch_deg, "roll_deg": self.roll_deg,
            },
            "vessel": {
                "lat": self.vessel_lat_deg, "lon": self.vessel_lon_deg,
                "heading_deg": self.vessel_heading_deg,
            },
            "water_level_m": self.water_level_m,
        }
        if self.timestamp is not None:
            data["timestamp"] = self.timestamp
        if self.sun_elevation_deg is not None and self.sun_azimuth_deg is not None:
            data["sun"] = {"elevation_deg": self.sun_elevation_deg,
                           "azimuth_deg": self.sun_azimuth_deg}
        for (section, key), name in FRAME_SIGMA_FIELDS.items():
            if name in self.sensor_sigmas:
                data[section][key] = self.sensor_sigmas[name]
        if self.vessel_dead_reckoned_s is not None:
            data["vessel"]["dead_reckoned_s"] = self.vessel_dead_reckoned_s
        for section, velocity in (("uav", self.uav_velocity_en_mps),
                                  ("vessel", self.vessel_velocity_en_mps)):
            if velocity is not None:
                data[section]["velocity_en_mps"] = list(velocity)
        for key, value in (("velocity_sigma_mps", self.vessel_velocity_sigma_mps),
                           ("yaw_rate_deg_s", self.vessel_yaw_rate_deg_s),
                           ("yaw_rate_sigma_deg_s", self.vessel_yaw_rate_sigma_deg_s)):
            if value is not None:
                data["vessel"][key] = value
        data.update(self.extra)
        return data


class _Reader:
    """Typed field access that raises ``InputError(file, dotted.field, ...)``."""

    def __init__(self, source: str | None) -> None:
        self.source = source

    def section(self, data: dict, key: str, prefix: str = "") -> dict:
        name = f"{prefix}{key}"
        if key not in data:
            raise InputError(self.source, name, "missing")
        value = data[key]
        if not isinstance(value, dict):
            raise InputError(self.source, name, f"expected an object, got {type(value).__name__}")
        return value

    def number(
        self, data: dict, key: str, prefix: str = "", *, default: float | None = None,
        low: float | None = None, high: float | None = None,
    ) -> float:
        name = f"{prefix}{key}"
        if key not in data or data[key] is None:
            if default is not None:
                return default
            raise InputError(self.source, name, "missing")
        value = data[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(self.source, name, f"expected a number, got {brief(value)}")
        try:
            value = float(value)
        except OverflowError:           # a whole number of 400 digits
            raise InputError(self.source, name,
                             f"not a finite number, got {brief(data[key])}") from None
        if not math.isfinite(value):
            raise InputError(self.source, name, f"must be finite, got {value}")
        if (low is not None and value < low) or (high is not None and value > high):
            raise InputError(self.source, name, f"{value} is outside [{low}, {high}]")
        return value

    def optional_number(self, data: dict, key: str, prefix: str, low: float, high: float
                        ) -> float | None:
        """A number that may be absent (or null): None then."""
        if data.get(key) is None:
            return None
        return self.number(data, key, prefix, low=low, high=high)

    def optional_pair(self, data: dict, key: str, prefix: str, bound: float
                      ) -> tuple[float, float] | None:
        """Two numbers ``[a, b]`` within ``±bound`` that may be absent (None then)."""
        value = data.get(key)
        if value is None:
            return None
        if not isinstance(value, list) or len(value) != 2:
            raise InputError(self.source, f"{prefix}{key}",
                             f"expected two numbers [east, north], got {brief(value)}")
        pair = {f"{key}[0]": value[0], f"{key}[1]": value[1]}
        east, north = (self.number(pair, name, prefix, low=-bound, high=bound) for name in pair)
        return east, north


#: how far the image's aspect may differ from the sensor's for ``focal_length_mm`` (a share)
SENSOR_ASPECT_TOLERANCE = 0.01


def _check_sensor_aspect(src, width: int, height: int, sensor_w_mm: float, sensor_h_mm: float,
                         focal_mm: float) -> None:
    """``fx = f·width/sensor_width`` and ``fy = f·height/sensor_height`` hold only for an image
    of the whole sensor. A 16:9 video from a 4:3 sensor is a crop of it: the two would give
    pixels 1.33 times taller than wide, and distances off by up to a third, so such a camera
    block is refused with the fx of the common crop (the sensor's full width) to check."""
    image_aspect, sensor_aspect = width / height, sensor_w_mm / sensor_h_mm
    if abs(image_aspect / sensor_aspect - 1.0) <= SENSOR_ASPECT_TOLERANCE:
        return
    hint = ""
    if image_aspect > sensor_aspect >= 1.0:     # a wide crop of a landscape sensor
        hint = (" (for a video across the sensor's full width, as DJI's, fx = fy = "
                f"{focal_mm * width / sensor_w_mm:.1f})")
    raise InputError(src, "camera.sensor_height_mm",
                     f"the sensor ({sensor_w_mm:g} x {sensor_h_mm:g} mm, {sensor_aspect:.3f}:1) "
                     f"and the image ({width}x{height}, {image_aspect:.3f}:1) differ in aspect: "
                     "the image is a crop of the sensor, or turned, and which is not known; "
                     f"give fx and fy in pixels{hint}")


def _parse_camera(reader: _Reader, cam: dict, base_dir: Path | None) -> CameraIntrinsics:
    src = reader.source
    if "calibration" in cam:
        if not isinstance(cam["calibration"], str) or not cam["calibration"]:
            raise InputError(src, "camera.calibration",
                             f"expected a calibration file path, got {brief(cam['calibration'])}")
        calib = Path(cam["calibration"])
        if base_dir is not None and not calib.is_absolute():
            calib = base_dir / calib
        return load_camera_calibration(calib)
    for key in ("width", "height"):
        value = cam.get(key)
        if value is None:
            raise InputError(src, f"camera.{key}", "missing")
        if (isinstance(value, bool) or not isinstance(value, (int, float))
                or (isinstance(value, float) and not value.is_integer())):
            raise InputError(src, f"camera.{key}",
                             f"expected a whole number of pixels, got {brief(value)}")
        if not 0 < value <= MAX_IMAGE_SIDE_PX:
            raise InputError(src, f"camera.{key}", f"expected a whole number of pixels from 1 to "
                             f"{MAX_IMAGE_SIDE_PX}, got {brief(value)}")
    width, height = int(cam["width"]), int(cam["height"])
    distortion = cam.get("distortion") or []
    if not isinstance(distortion, list) or not all(
        isinstance(c, (int, float)) and not isinstance(c, bool) for c in distortion
    ):
        raise InputError(src, "camera.distortion", "expected a list of numbers (k1, k2, p1, p2[, k3])")
    try:
        distortion = tuple(float(c) for c in distortion)
    except OverflowError:               # a whole number of 400 digits
        raise InputError(src, "camera.distortion", "coefficients must be finite numbers") from None
    if "fx" in cam:
        intr = CameraIntrinsics(
            width=width, height=height,
            fx=reader.number(cam, "fx", "camera.", low=1e-6),
            fy=reader.number(cam, "fy", "camera.", low=1e-6),
            cx=reader.number(cam, "cx", "camera.", default=(width - 1) / 2.0),
            cy=reader.number(cam, "cy", "camera.", default=(height - 1) / 2.0),
            distortion=distortion,
        )
    elif "focal_length_mm" in cam:
        sensor_w = reader.number(cam, "sensor_width_mm", "camera.", low=1e-6)
        sensor_h = reader.number(cam, "sensor_height_mm", "camera.", low=1e-6)
        focal = reader.number(cam, "focal_length_mm", "camera.", low=1e-6)
        _check_sensor_aspect(src, width, height, sensor_w, sensor_h, focal)
        intr = CameraIntrinsics.from_sensor(width, height, sensor_w, sensor_h, focal, distortion)
    else:
        raise InputError(src, "camera.fx", "missing (give fx/fy/cx/cy, focal_length_mm with "
                         "sensor_width_mm/sensor_height_mm, or calibration)")
    intr.validate(src)
    return intr


#: plausibility limits of a frame's pose (FrameGeometry.check_plausible)
MAX_HEIGHT_ABOVE_WATER_M = 3000.0
MAX_VESSEL_RANGE_M = 10_000.0

#: bound on a velocity in frame metadata (m/s): faster than any drone or ship
MAX_SPEED_MPS = 200.0
#: bound on a vessel's rate of turn and its sigma in frame metadata (deg/s): a jet ski's
MAX_TURN_DEG_S = 180.0
#: bound on ``vessel.dead_reckoned_s`` (s): an hour
MAX_DEAD_RECKONED_S = 3600.0


def _frame_sigmas(reader: _Reader, sections: dict[str, dict]) -> dict[str, float]:
    """The optional sensor sigmas of a frame (FRAME_SIGMA_FIELDS), by SensorSigmas name."""
    found = {}
    for (section, key), name in FRAME_SIGMA_FIELDS.items():
        value = reader.optional_number(sections[section], key, f"{section}.", 0.0, 1000.0)
        if value is not None:
            found[name] = value
    return found


_KNOWN_KEYS = {"schema", "image", "timestamp", "camera", "uav", "camera_attitude", "vessel",
               "water_level_m", "sun"}


def _parse_sun(reader: _Reader, data: dict) -> tuple[float | None, float | None]:
    """The optional ``sun`` block: ``elevation_deg`` in [-90, 90], ``azimuth_deg`` in
    [-360, 360] (clockwise from north), both required when the block is there."""
    if data.get("sun") is None:
        return None, None
    sun = reader.section(data, "sun")
    return (reader.number(sun, "elevation_deg", "sun.", low=-90, high=90),
            reader.number(sun, "azimuth_deg", "sun.", low=-360, high=360))


def parse_frame_metadata(
    data: Any, source: str | Path | None = None, *, camera: CameraIntrinsics | None = None,
    base_dir: Path | None = None,
) -> FrameMetadata:
    """Validate a ``harborsight.frame/1`` dict; ``camera`` overrides the file's intrinsics."""
    src = str(source) if source is not None else None
    reader = _Reader(src)
    if not isinstance(data, dict):
        raise InputError(src, None, "expected a JSON object")
    schema = data.get("schema", FRAME_SCHEMA)
    if schema != FRAME_SCHEMA:
        raise InputError(src, "schema", f"expected {FRAME_SCHEMA!r}, got {brief(schema)}")
    image = data.get("image")
    if not isinstance(image, str) or not image:
        raise InputError(src, "image", "missing (the image file name)")
    intr = camera or _parse_camera(reader, reader.section(data, "camera"), base_dir)
    timestamp = data.get("timestamp")
    if timestamp is not None:
        try:
            datetime.fromisoformat(timestamp)
        except (TypeError, ValueError):
            raise InputError(src, "timestamp",
                             f"expected an ISO 8601 time, got {brief(timestamp)}") from None

    uav = reader.section(data, "uav")
    att = reader.section(data, "camera_attitude")
    ves = reader.section(data, "vessel")
    sun_elevation_deg, sun_azimuth_deg = _parse_sun(reader, data)
    meta = FrameMetadata(
        image=image,
        camera=intr,
        uav_lat_deg=reader.number(uav, "lat", "uav.", low=-90, high=90),
        uav_lon_deg=reader.number(uav, "lon", "uav.", low=-180, high=180),
        uav_alt_m=reader.number(uav, "alt_m", "uav."),
        yaw_deg=reader.number(att, "yaw_deg", "camera_attitude.", low=-360, high=360),
        pitch_deg=reader.number(att, "pitch_deg", "camera_attitude.", low=-180, high=180),
        roll_deg=reader.number(att, "roll_deg", "camera_attitude.", default=0.0,
                               low=-180, high=180),
        vessel_lat_deg=reader.number(ves, "lat", "vessel.", low=-90, high=90),
        vessel_lon_deg=reader.number(ves, "lon", "vessel.", low=-180, high=180),
        vessel_heading_deg=reader.number(ves, "heading_deg", "vessel.", low=-360, high=360),
        water_level_m=reader.number(data, "water_level_m", default=0.0),
        timestamp=timestamp,
        extra={k: v for k, v in data.items() if k not in _KNOWN_KEYS},
        source=src,
        sensor_sigmas=_frame_sigmas(reader, {"uav": uav, "camera_attitude": att,
                                             "vessel": ves}),
        uav_velocity_en_mps=reader.optional_pair(uav, "velocity_en_mps", "uav.", MAX_SPEED_MPS),
        vessel_velocity_en_mps=reader.optional_pair(ves, "velocity_en_mps", "vessel.",
                                                    MAX_SPEED_MPS),
        vessel_velocity_sigma_mps=reader.optional_number(ves, "velocity_sigma_mps", "vessel.",
                                                         0.0, MAX_SPEED_MPS),
        vessel_yaw_rate_deg_s=reader.optional_number(ves, "yaw_rate_deg_s", "vessel.",
                                                     -MAX_TURN_DEG_S, MAX_TURN_DEG_S),
        vessel_yaw_rate_sigma_deg_s=reader.optional_number(ves, "yaw_rate_sigma_deg_s", "vessel.",
                                                           0.0, MAX_TURN_DEG_S),
        sun_elevation_deg=sun_elevation_deg,
        sun_azimuth_deg=sun_azimuth_deg,
        vessel_dead_reckoned_s=reader.optional_number(ves, "dead_reckoned_s", "vessel.",
                                                      0.0, MAX_DEAD_RECKONED_S),
    )
    if meta.height_above_water_m <= 0:
        raise InputError(
            src, "uav.alt_m",
            f"{meta.uav_alt_m} m is at or below water_level_m {meta.water_level_m} m",
        )
    return meta


def load_frame_metadata(
    path: str | Path, *, camera: CameraIntrinsics | None = None
) -> FrameMetadata:
    """Read and validate one frame JSON file."""
    path = Path(path)
    return parse_frame_metadata(read_frame_json(path), path, camera=camera, base_dir=path.parent)


def read_frame_json(path: Path) -> object:
    """The JSON value of a frame file, unvalidated; :class:`InputError` if it cannot be read
    or is not JSON (:func:`parse_json_text`)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(path, None, "frame metadata file not found") from None
    except IsADirectoryError:
        raise InputError(path, None, "is a folder, not a file") from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(path, None, f"not valid JSON: {_not_utf8_message(data, exc)}") from None
    return parse_json_text(text, path)


def _not_utf8_message(data: bytes, exc: UnicodeDecodeError) -> str:
    """Where bytes stop being UTF-8: 'not UTF-8 text: byte 0xe9 on line 3'."""
    line = data.count(b"\n", 0, exc.start) + 1
    return f"not UTF-8 text: byte 0x{data[exc.start]:02x} on line {line} (save the file as UTF-8)"


def parse_frame_metadata_untimed_on_error(
    data: object, source: str | Path, **options
) -> tuple[FrameMetadata, str | None]:
    """:func:`parse_frame_metadata`, but a frame whose only fault is its ``timestamp`` is
    returned without one, with the error as the second value: a flight run measures such a
    frame (its distances do not depend on the time) and leaves it out of the closing speeds."""
    try:
        return parse_frame_metadata(data, source, **options), None
    except InputError as exc:
        if exc.field != "timestamp" or not isinstance(data, dict):
            raise
        untimed = {key: value for key, value in data.items() if key != "timestamp"}
        return parse_frame_metadata(untimed, source, **options), str(exc)


def _sun_of(meta: FrameMetadata) -> tuple[float, float] | None:
    """The frame's ``sun`` block; for a simulator frame written before that block existed,
    the sun it was rendered with (``simulation.environment``), which its synthetic time does
    not give."""
    if meta.sun_elevation_deg is not None and meta.sun_azimuth_deg is not None:
        return meta.sun_elevation_deg, meta.sun_azimuth_deg
    simulation = meta.extra.get("simulation")
    env = simulation.get("environment") if isinstance(simulation, dict) else None
    if isinstance(env, dict):
        el, az = env.get("sun_elevation_deg"), env.get("sun_azimuth_deg")
        if all(isinstance(v, (int, float)) and math.isfinite(v) for v in (el, az)):
            return float(el), float(az)
    return None


def _aware_time(timestamp: str | None) -> datetime | None:
    """The frame's time when it carries a UTC offset (``Z`` or ``+hh:mm``), else None."""
    if timestamp is None:
        return None
    try:
        when = datetime.fromisoformat(timestamp)
    except (TypeError, ValueError):
        return None
    return when if when.tzinfo is not None else None


@dataclass(frozen=True)
class FrameGeometry:
    """The posed scene of one frame in local ENU (origin: vessel GPS at the water level)."""

    origin: GeoOrigin
    camera: Camera
    vessel_heading_rad: float
    vessel_position_enu: np.ndarray = field(default_factory=lambda: np.zeros(2))
    source: str | None = None
    #: the sun's elevation and azimuth (degrees) as the frame gives them, or the frame's time
    #: (with its UTC offset) to compute them from: :meth:`sun_ray_enu`
    sun_deg: tuple[float, float] | None = None
    time: datetime | None = None

    def sun_ray_enu(self) -> np.ndarray | None:
        """The direction sunlight travels here (:mod:`harborsight.geometry.sun`), from the
        frame's ``sun`` block, else from its time and place; None when neither is known or
        the sun is too low to cast a usable shadow."""
        from harborsight.geometry.sun import sun_position_deg, sun_ray_enu

        if self.sun_deg is not None:
            return sun_ray_enu(*self.sun_deg)
        if self.time is None or self.time.tzinfo is None:
            return None
        return sun_ray_enu(*sun_position_deg(self.origin.lat_deg, self.origin.lon_deg, self.time))

    @classmethod
    def from_metadata(cls, meta: FrameMetadata) -> FrameGeometry:
        origin = GeoOrigin(meta.vessel_lat_deg, meta.vessel_lon_deg, meta.water_level_m)
        cam_enu = geodetic_to_enu(meta.uav_lat_deg, meta.uav_lon_deg, meta.uav_alt_m, origin)
        rotation = world_from_camera_rotation(
            math.radians(meta.yaw_deg), math.radians(meta.pitch_deg), math.radians(meta.roll_deg)
        )
        geometry = cls(
            origin=origin,
            camera=Camera(meta.camera, cam_enu, rotation),
            vessel_heading_rad=math.radians(meta.vessel_heading_deg),
            source=meta.source,
            sun_deg=_sun_of(meta),
            time=_aware_time(meta.timestamp),
        )
        geometry.check_plausible(meta)
        geometry.check_sees_water()
        return geometry

    def check_plausible(self, meta: FrameMetadata) -> None:
        """Refuse poses outside what the flat water-plane model and a drone can mean: a
        height above the water of more than :data:`MAX_HEIGHT_ABOVE_WATER_M` or a vessel
        more than :data:`MAX_VESSEL_RANGE_M` from the drone horizontally (the earth's curve
        drops d²/2R below the tangent plane: 7.8 m at 10 km, 2.5 km at 180 km, where a
        clearance came out at -14.6 m)."""
        height_m = meta.height_above_water_m
        if height_m > MAX_HEIGHT_ABOVE_WATER_M:
            raise InputError(self.source, "uav.alt_m",
                             f"{height_m:.0f} m above the water (alt_m {meta.uav_alt_m} - "
                             f"water_level_m {meta.water_level_m}): more than "
                             f"{MAX_HEIGHT_ABOVE_WATER_M:.0f} m, not a drone over a harbour")
        range_m = float(np.hypot(*self.camera.position_enu[:2]))
        if range_m > MAX_VESSEL_RANGE_M:
            raise InputError(self.source, "vessel.lat",
                             f"the vessel is {range_m / 1000:.1f} km from the drone "
                             f"horizontally: more than {MAX_VESSEL_RANGE_M / 1000:.0f} km, where "
                             "the flat water plane no longer holds (check both positions)")

    def check_sees_water(self) -> None:
        """Raise unless some of the image looks down onto the water plane."""
        intr = self.camera.intrinsics
        us = np.linspace(0, intr.width - 1, 9)
        vs = np.linspace(0, intr.height - 1, 9)
        grid = np.array([(u, v) for u in us for v in vs])
        _, valid = self.camera.back_project_to_plane(grid)
        if not valid.any():
            raise InputError(
                self.source, "camera_attitude.pitch_deg",
                "the camera looks at or above the horizon: no pixel sees the water plane",
            )

    def vessel_to_enu(self, points_v: np.ndarray) -> np.ndarray:
        """Vessel-frame points (x bow, y starboard[, z down]) to ENU ``(N, 3)``."""
        points_v = np.atleast_2d(np.asarray(points_v, float))
        if points_v.shape[1] == 2:
            points_v = np.column_stack((points_v, np.zeros(len(points_v))))
        enu = points_v @ enu_from_vessel_rotation(self.vessel_heading_rad).T
        enu[:, :2] += self.vessel_position_enu
        return enu

    def vessel_from_world_2d(self) -> np.ndarray:
        """3x3 homogeneous map of water-plane ENU (e, n) to vessel (x bow, y starboard)."""
        s, c = math.sin(self.vessel_heading_rad), math.cos(self.vessel_heading_rad)
        rot = np.array([[s, c], [c, -s]])
        return np.block([[rot, -(rot @ self.vessel_position_enu)[:, None]],
                         [np.zeros((1, 2)), np.ones((1, 1))]])

    def pixels_to_vessel_xy(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels back-projected onto the water plane, in the vessel frame: ``(xy, valid)``."""
        return self.camera.pixels_to_plane_xy(uv, 0.0, post=self.vessel_from_world_2d())

    def enu_to_vessel_xy(self, points_enu: np.ndarray) -> np.ndarray:
        """ENU points (on the water plane) to vessel-frame x (bow), y (starboard)."""
        T = self.vessel_from_world_2d()
        return np.atleast_2d(points_enu)[:, :2] @ T[:2, :2].T + T[:2, 2]
