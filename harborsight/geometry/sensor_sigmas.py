"""How wrong each pose sensor may be: one standard deviation per error source.

A clearance depends on the drone's and the vessel's positions, the vessel's heading, the
camera's yaw and tilt and its height above the water. Each is measured by a sensor with a
known class of error. Where a frame's metadata carries its own figure (a receiver's
reported accuracy, an RTK flag turned into metres by a telemetry reader) that figure is
used; else the value given with ``--sigma NAME=VALUE``; else the default of the sensor class
below. Defaults (one sigma):

=====================  =========  ==========================================================
name                   default    source
=====================  =========  ==========================================================
``uav_gps``            2.0 m      drone receiver, horizontal RMS (DRMS) of one standalone
                                  GPS; per axis ``DRMS / sqrt(2)``. Classes: ``rtk`` 0.02,
                                  ``dgps`` 0.5, ``standalone`` 2.0
``vessel_gps``         2.0 m      the vessel's receiver, as above
``vessel_heading_deg`` 2.0 deg    magnetic compass; ``gnss`` (dual-antenna) 0.3, ``gyro`` 0.5
``camera_yaw_deg``     2.0 deg    the drone's compass, which sets the gimbal's yaw
``camera_tilt_deg``    0.5 deg    a stabilised gimbal's pitch and roll, each
``height_m``           1.0 m      the drone's altitude (barometric; a frame's ``uav.alt_sigma_m``)
``water_level_m``      0.3 m      the water level under it (tide, chart datum); adds to
                                  ``height_m`` in quadrature
``focal_rel``          0.005      the camera's focal length, relative: a calibration (a
                                  careful one 0.002; a datasheet's focal length 0.01-0.02,
                                  a video mode that crops the sensor more). Off by ``ε`` it
                                  scales every back-projected point about the nadir as a
                                  height off by ``-ε·h`` would (exactly for a camera looking
                                  straight down), so it enters as that height, in
                                  quadrature (:meth:`SensorSigmas.scale_height_m`)
``clock_s``            0.05 s     video vs telemetry clocks (needs the frames' velocities)
``edge_px``            4.0 px     where the mask puts the obstacle's edge, and a model's other
                                  small errors near the hull: calibrated for the shipped model
                                  on the seed-7 bench (simulator frames; real frames are worse);
                                  1 px for masks read from files (it also takes the
                                  planar assumption's error: quay tops above the water)
``edge_m``             0.5 m      the same edge's error that does not shrink with the pixel, in
                                  metres on the water, added to ``edge_px`` in quadrature: a
                                  model puts a fender, a shadow or an overhang on the wrong side
                                  as much at 30 m as at 150 m, where ``edge_px`` alone would
                                  make a low drone's bound too tight. 0 for masks read from
                                  files
=====================  =========  ==========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

#: horizontal RMS error (m) of one receiver, by class
GPS_CLASSES = {"rtk": 0.02, "dgps": 0.5, "standalone": 2.0}
#: one sigma (deg) of a vessel's heading sensor, by class
HEADING_CLASSES = {"magnetic": 2.0, "gnss": 0.3, "gyro": 0.5}
#: the segmentation edge's sigma (px) of a mask read from a file (hand or simulator labels)
LABEL_FILE_EDGE_PX = 1.0
#: and its metric floor (m): none for a mask read from a file
LABEL_FILE_EDGE_M = 0.0


def _parse_class_or_number(text: str, classes: dict[str, float], unit: str) -> float:
    key = str(text).strip().lower()
    if key in classes:
        return classes[key]
    try:
        value = float(key)
    except ValueError:
        raise ValueError(f"expected {', '.join(classes)} or {unit}, got {text!r}") from None
    if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
        raise ValueError(f"expected {unit} from 0 to 1000, got {text!r}")
    return value


def parse_gps_noise(text: str) -> float:
    """``rtk``, ``dgps``, ``standalone`` or a number of metres (horizontal RMS)."""
    return _parse_class_or_number(text, GPS_CLASSES, "metres")


@dataclass(frozen=True)
class SensorSigmas:
    """One sigma of every error source (metres, degrees, seconds, pixels); see module."""

    uav_gps: float = GPS_CLASSES["standalone"]
    vessel_gps: float = GPS_CLASSES["standalone"]
    vessel_heading_deg: float = HEADING_CLASSES["magnetic"]
    camera_yaw_deg: float = 2.0
    camera_tilt_deg: float = 0.5
    height_m: float = 1.0
    water_level_m: float = 0.3
    focal_rel: float = 0.005
    clock_s: float = 0.05
    edge_px: float = 4.0
    edge_m: float = 0.5

    def __post_init__(self) -> None:
        for name in self.names():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and 0.0 <= value <= 1000.0):
                raise ValueError(f"sigma {name} must be a number from 0 to 1000, got {value!r}")

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    @property
    def height_above_water_m(self) -> float:
        """One sigma of the height above the water: altitude and water level together."""
        return math.hypot(self.height_m, self.water_level_m)

    def scale_height_m(self, height_m: float) -> float:
        """One sigma of the scene's scale, as a height at ``height_m`` above the water: the
        height's own and the focal length's (``focal_rel · height_m``) in quadrature."""
        return math.hypot(self.height_above_water_m, self.focal_rel * max(height_m, 0.0))

    @property
    def uav_axis_m(self) -> float:
        """Per-axis sigma of the drone's horizontal position (DRMS / sqrt 2)."""
        return self.uav_gps / math.sqrt(2.0)

    @property
    def vessel_axis_m(self) -> float:
        return self.vessel_gps / math.sqrt(2.0)

    def hull_shift_axis_m(self, height_m: float, nadir_offset_m: float) -> float:
        """One sigma per axis of where the sensors put the hull on the water, relative to
        what the camera sees: both receivers per axis; a camera tilt moves the scene by
        ``h tan(tilt)`` along each of its two axes; a camera yaw turns the scene about the
        nadir, moving a hull ``r`` from it by ``r yaw`` across that line, half of that
        variance per axis: ``sqrt(σ_uav² + σ_vessel² + (h σ_tilt)² + (r σ_yaw)² / 2)``."""
        tilt_m = max(height_m, 0.0) * math.tan(math.radians(self.camera_tilt_deg))
        yaw_m = max(nadir_offset_m, 0.0) * math.radians(self.camera_yaw_deg)
        return math.sqrt(self.uav_axis_m ** 2 + self.vessel_axis_m ** 2 + tilt_m ** 2
                         + 0.5 * yaw_m ** 2)

    @property
    def hull_heading_deg(self) -> float:
        """One sigma of the hull's heading in the image: the vessel's compass and the
        camera's yaw, which turns the whole scene."""
        return math.hypot(self.vessel_heading_deg, self.camera_yaw_deg)

    def with_values(self, values: dict[str, float]) -> SensorSigmas:
        """A copy with some sigmas replaced (unknown names raise ValueError)."""
        unknown = sorted(set(values) - set(self.names()))
        if unknown:
            raise ValueError(f"unknown sigma(s) {', '.join(unknown)}; known: "
                             f"{', '.join(self.names())}")
        return replace(self, **values)

    def to_dict(self) -> dict[str, float]:
        return {name: round(float(getattr(self, name)), 4) for name in self.names()}


def parse_sigma_option(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` of ``--sigma`` (VALUE may name a class: ``uav_gps=rtk``,
    ``vessel_heading_deg=gnss``); raises ValueError naming what is wrong."""
    name, sep, value = str(text).partition("=")
    name = name.strip().replace("-", "_")
    if not sep or not name:
        raise ValueError(f"expected NAME=VALUE, got {text!r}")
    if name not in SensorSigmas.names():
        raise ValueError(f"unknown sigma {name!r}; known: {', '.join(SensorSigmas.names())}")
    classes = (GPS_CLASSES if name in ("uav_gps", "vessel_gps")
               else HEADING_CLASSES if name == "vessel_heading_deg" else {})
    return name, _parse_class_or_number(value, classes, "a number")


#: frame metadata fields (``harborsight.frame/1``, optional) that carry a sensor's own sigma,
#: and the :class:`SensorSigmas` name each sets. Positions are per-axis sigmas in the file.
FRAME_SIGMA_FIELDS = {
    ("uav", "position_sigma_m"): "uav_gps",
    ("uav", "alt_sigma_m"): "height_m",
    ("camera_attitude", "yaw_sigma_deg"): "camera_yaw_deg",
    ("camera_attitude", "tilt_sigma_deg"): "camera_tilt_deg",
    ("vessel", "position_sigma_m"): "vessel_gps",
    ("vessel", "heading_sigma_deg"): "vessel_heading_deg",
}


#: how a vessel's pose carried forward by its speed and course (dead reckoning between AIS
#: reports) drifts from the truth, one sigma: the speed and course it was carried with
#: (m/s; AIS gives speed in 0.1 kn and a course that wanders at berthing speeds), its change
#: of speed or course since (m/s², a vessel berthing under thrusters), and its turn (deg/s;
#: the heading is held: AIS's rate of turn is coarse and often not available)
DEAD_RECKONING_SPEED_MPS = 0.1
DEAD_RECKONING_ACCEL_MPS2 = 0.05
DEAD_RECKONING_TURN_DEG_S = 0.5


#: the longest dead reckoning (s) a vessel pose is measured with: 3.8 m and 6 degrees of
#: drift (a class A AIS transponder under way reports every 10 s; one report missed leaves a
#: gap). A frame carried longer (a class B transponder reports every 30 s, or every 3 min
#: under 2 kn) is measured only where the frames before it placed the vessel in the image
#: (:mod:`harborsight.flight.pose_carry`)
MAX_DEAD_RECKONED_S = 12.0


def dead_reckoning_drift(seconds: float) -> tuple[float, float]:
    """One sigma of a dead-reckoned vessel's horizontal position (DRMS, m) and heading (deg)
    after ``seconds``: ``sqrt((σ_v t)² + (a t² / 2)²)`` and ``ω t`` (constants above); added
    in quadrature to the receiver's and the compass's own."""
    t = max(float(seconds), 0.0)
    return (math.hypot(DEAD_RECKONING_SPEED_MPS * t, 0.5 * DEAD_RECKONING_ACCEL_MPS2 * t * t),
            DEAD_RECKONING_TURN_DEG_S * t)


def sigmas_for_frame(base: SensorSigmas, frame_sigmas: dict[str, float],
                     vessel_dead_reckoned_s: float | None = None) -> SensorSigmas:
    """``base`` with the frame's own figures (``FrameMetadata.sensor_sigmas``: keys as
    :data:`FRAME_SIGMA_FIELDS` values; positions per axis, turned into DRMS here), and a
    vessel pose dead-reckoned for ``vessel_dead_reckoned_s`` widened by
    :func:`dead_reckoning_drift`."""
    values = dict(frame_sigmas)
    for name in ("uav_gps", "vessel_gps"):
        if name in values:
            values[name] = values[name] * math.sqrt(2.0)
    sigmas = base.with_values(values) if values else base
    if vessel_dead_reckoned_s:
        position_m, heading_deg = dead_reckoning_drift(vessel_dead_reckoned_s)
        sigmas = replace(sigmas, vessel_gps=min(math.hypot(sigmas.vessel_gps, position_m), 1000.0),
                         vessel_heading_deg=min(math.hypot(sigmas.vessel_heading_deg,
                                                           heading_deg), 1000.0))
    return sigmas
