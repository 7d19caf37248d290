"""Noisy-sensor variants of frame metadata, the true pose kept as ground truth.

Real frames come with the errors of real sensors; the simulator's are exact. To measure
what those errors do to the distances (and what pose refinement wins back), every pose
field a sensor delivers is perturbed with independent Gaussian errors, seeded per frame:

* drone and vessel GPS: each receiver's horizontal position, per-axis sigma
  ``gps_m / sqrt(2)`` so that ``gps_m`` is the horizontal RMS error (DRMS) of one receiver
  (:data:`GPS_CLASSES`: RTK 0.02 m, DGPS 0.5 m, standalone 2 m);
* drone camera yaw and vessel heading (compasses): sigma ``heading_deg`` each;
* drone height above the water (barometer, water level): sigma ``height_m``;
* the vessel's ground velocity (its receiver's Doppler velocity) and rate of turn (its rate
  gyro), where the frame gives them (a flight's frames do): sigma ``velocity_mps`` per axis
  and ``yaw_rate_deg_s``, drawn after the others, so that a frame's other errors are those
  of a set made without them.

Real GPS and compass errors drift slowly rather than jump from frame to frame, and a filter
cannot average a drift away. With ``correlation_s`` > 0 the errors of a flight's frames (in
time order) follow a first-order Gauss-Markov process: ``e_k = rho e_(k-1) + sqrt(1 - rho²)
w_k``, ``rho = exp(-dt / correlation_s)``, ``w_k`` the frame's own draw, so every frame keeps
the stated sigma and errors ``correlation_s`` apart are correlated by ``1/e``.

Each noisy frame carries the sigmas it was drawn with (``uav.position_sigma_m``,
``uav.alt_sigma_m``, ``camera_attitude.yaw_sigma_deg``, ``vessel.position_sigma_m``,
``vessel.heading_sigma_deg``, ``vessel.velocity_sigma_mps``,
``vessel.yaw_rate_sigma_deg_s``), as a telemetry reader writes
a receiver's reported accuracy, so that the distances' sigmas follow them. The true values move to
``ground_truth.true_pose`` and the errors drawn to ``ground_truth.pose_errors``; the
ground-truth distances themselves do not change (they are properties of the scene, not of
the sensors).
"""

from __future__ import annotations

import copy
import math
import shutil
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from harborsight.errors import HarborsightError, InputError
from harborsight.files import natural_key, strict_json, write_text_atomic
from harborsight.geometry.geodesy import GeoOrigin, enu_to_geodetic
from harborsight.geometry.sensor_sigmas import GPS_CLASSES, parse_gps_noise
from harborsight.text_formats import parse_json_text

__all__ = ["GPS_CLASSES", "PoseNoise", "add_pose_noise", "parse_gps_noise", "write_noisy_dataset"]

@dataclass(frozen=True)
class PoseNoise:
    """One sigma of each sensor error (metres, degrees); all zero is exact sensors."""

    gps_m: float = 0.0
    heading_deg: float = 0.0
    height_m: float = 0.0
    #: time constant (s) of the errors' drift over a flight; 0: independent per frame
    correlation_s: float = 0.0
    #: one sigma (m/s, per axis) of the vessel's velocity, and (deg/s) of its rate of turn,
    #: where a frame gives them
    velocity_mps: float = 0.0
    yaw_rate_deg_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("gps_m", "heading_deg", "height_m", "velocity_mps", "yaw_rate_deg_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
                raise ValueError(f"{name} must be a number from 0 to 1000, got {value}")
        if not (math.isfinite(self.correlation_s) and 0.0 <= self.correlation_s <= 1e6):
            raise ValueError(f"correlation_s must be a number from 0 to 1e6, got {self.correlation_s}")

    def to_dict(self) -> dict[str, float]:
        data = {"gps_m": self.gps_m, "heading_deg": self.heading_deg, "height_m": self.height_m}
        if self.correlation_s:
            data["correlation_s"] = self.correlation_s
        if self.velocity_mps:
            data["velocity_mps"] = self.velocity_mps
        if self.yaw_rate_deg_s:
            data["yaw_rate_deg_s"] = self.yaw_rate_deg_s
        return data


def _moved(lat_deg: float, lon_deg: float, alt_m: float, east_m: float, north_m: float
           ) -> tuple[float, float]:
    lat, lon, _ = enu_to_geodetic(np.array([east_m, north_m, 0.0]),
                                  GeoOrigin(lat_deg, lon_deg, alt_m))
    return float(lat), float(lon)


def add_pose_noise(frame: dict[str, Any], noise: PoseNoise, rng: np.random.Generator,
                   previous: dict[str, Any] | None = None, rho: float = 0.0) -> dict[str, Any]:
    """A copy of a ``harborsight.frame/1`` document with sensor errors drawn from ``rng``
    (module docstring). ``frame`` must hold ``uav``, ``camera_attitude`` and ``vessel``.
    With ``previous`` (the previous frame's ``ground_truth.pose_errors``) and ``rho`` the
    errors continue that frame's: ``rho previous + sqrt(1 - rho²) draw``."""
    if "true_pose" in (frame.get("ground_truth") or {}):
        raise ValueError("the frame's pose is noisy already (ground_truth.true_pose is set)")
    noisy = copy.deepcopy(frame)
    uav, attitude, vessel = noisy["uav"], noisy["camera_attitude"], noisy["vessel"]
    true_pose = {"uav": dict(uav), "camera_attitude": {"yaw_deg": attitude["yaw_deg"]},
                 "vessel": dict(vessel)}
    axis_m = noise.gps_m / math.sqrt(2.0)
    uav_en = rng.normal(0.0, axis_m, 2) if axis_m else np.zeros(2)
    vessel_en = rng.normal(0.0, axis_m, 2) if axis_m else np.zeros(2)
    uav_height = float(rng.normal(0.0, noise.height_m)) if noise.height_m else 0.0
    yaw_error, heading_error = (rng.normal(0.0, noise.heading_deg, 2) if noise.heading_deg
                                else np.zeros(2))
    fresh = math.sqrt(max(0.0, 1.0 - rho * rho))

    def continued(draw, key: str):
        """This frame's draw continuing the previous frame's error ``key``, where there is one:
        ``rho previous + sqrt(1 - rho²) draw``."""
        if previous is None or rho <= 0.0 or key not in previous:
            return draw
        if np.ndim(draw) == 0:
            return rho * float(previous[key]) + fresh * float(draw)
        return rho * np.asarray(previous[key], float) + fresh * draw

    uav_en, vessel_en = continued(uav_en, "uav_en_m"), continued(vessel_en, "vessel_en_m")
    uav_height = continued(uav_height, "uav_height_m")
    yaw_error = continued(yaw_error, "camera_yaw_deg")
    heading_error = continued(heading_error, "vessel_heading_deg")
    uav["lat"], uav["lon"] = _moved(uav["lat"], uav["lon"], uav["alt_m"], *uav_en)
    uav["alt_m"] = uav["alt_m"] + uav_height
    attitude["yaw_deg"] = (attitude["yaw_deg"] + float(yaw_error)) % 360.0
    vessel["lat"], vessel["lon"] = _moved(vessel["lat"], vessel["lon"], 0.0, *vessel_en)
    vessel["heading_deg"] = (vessel["heading_deg"] + float(heading_error)) % 360.0
    # the sensors' own figures, as a telemetry reader would write them (per-axis positions)
    uav["position_sigma_m"] = vessel["position_sigma_m"] = round(axis_m, 4)
    uav["alt_sigma_m"] = noise.height_m
    attitude["yaw_sigma_deg"] = vessel["heading_sigma_deg"] = noise.heading_deg
    truth = noisy.setdefault("ground_truth", {})
    truth["true_pose"] = true_pose
    truth["pose_errors"] = {
        "noise": noise.to_dict(),
        "uav_en_m": [round(float(v), 4) for v in uav_en],
        "uav_height_m": round(uav_height, 4),
        "camera_yaw_deg": round(float(yaw_error), 4),
        "vessel_en_m": [round(float(v), 4) for v in vessel_en],
        "vessel_heading_deg": round(float(heading_error), 4),
    }
    if noise.velocity_mps and vessel.get("velocity_en_mps") is not None:
        velocity_en = continued(rng.normal(0.0, noise.velocity_mps, 2), "vessel_velocity_en_mps")
        vessel["velocity_en_mps"] = [float(v) + float(e)
                                     for v, e in zip(vessel["velocity_en_mps"], velocity_en, strict=True)]
        vessel["velocity_sigma_mps"] = noise.velocity_mps
        truth["pose_errors"]["vessel_velocity_en_mps"] = [round(float(v), 4) for v in velocity_en]
    if noise.yaw_rate_deg_s and vessel.get("yaw_rate_deg_s") is not None:
        turn_error = continued(float(rng.normal(0.0, noise.yaw_rate_deg_s)), "vessel_yaw_rate_deg_s")
        vessel["yaw_rate_deg_s"] = float(vessel["yaw_rate_deg_s"]) + turn_error
        vessel["yaw_rate_sigma_deg_s"] = noise.yaw_rate_deg_s
        truth["pose_errors"]["vessel_yaw_rate_deg_s"] = round(turn_error, 4)
    return noisy


@dataclass
class NoisyDatasetResult:
    written: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)      # "file: reason"


def frame_rng(seed: int, stem: str) -> np.random.Generator:
    """The generator of one frame: the same errors for a frame whatever else is in the set."""
    return np.random.default_rng([seed, zlib.crc32(stem.encode("utf-8"))])


def _keep_vessel_spec_reachable(frame: dict[str, Any], source: Path, target: Path) -> None:
    """A relative ``vessel_spec`` that points outside the dataset (e.g. ``../vessels/...``)
    would not resolve from the copy: make it absolute. Relative names are looked up beside
    the frame JSON and in the dataset root, as the measurement does."""
    ref = frame.get("vessel_spec")
    if not isinstance(ref, str) or Path(ref).is_absolute():
        return
    reachable = any((base / ref).is_file() for base in (target.parent, target.parent.parent))
    if reachable:
        return
    for base in (source.parent, source.parent.parent):
        if (base / ref).is_file():
            frame["vessel_spec"] = str((base / ref).resolve())
            return


def write_noisy_dataset(source: Path, out: Path, noise: PoseNoise, seed: int = 0
                        ) -> NoisyDatasetResult:
    """A copy of a dataset (``frames/*.json`` and what sits beside it) whose frames carry
    sensor errors. ``frames/`` is written anew; every other entry (images, labels, vessels,
    dataset.json, ...) is linked (copied where links are not possible). A frame that cannot
    be read, or lacks a pose, is listed with its reason and skipped."""
    frames_dir = source / "frames"
    paths = sorted(frames_dir.glob("*.json"), key=lambda p: natural_key(p.name))
    if not paths:
        raise InputError(source, None, "no frames/*.json to add sensor noise to")
    out.mkdir(parents=True, exist_ok=True)
    for entry in sorted(source.iterdir()):
        target = out / entry.name
        if entry.name == "frames" or target.exists() or target.is_symlink():
            continue
        try:
            target.symlink_to(entry.resolve(), target_is_directory=entry.is_dir())
        except OSError:
            (shutil.copytree if entry.is_dir() else shutil.copy2)(entry, target)
    (out / "frames").mkdir(exist_ok=True)
    result = NoisyDatasetResult()
    previous: dict[str, Any] | None = None
    previous_time_s: float | None = None
    for path in paths:
        try:
            doc = parse_json_text(path.read_text(encoding="utf-8"), path)
            if not isinstance(doc, dict):
                raise InputError(path, None, "expected a JSON object")
            for key in ("uav", "camera_attitude", "vessel"):
                if not isinstance(doc.get(key), dict):
                    raise InputError(path, key, "missing: a pose is needed to add noise to")
            time_s = _time_s(doc)
            rho = 0.0
            if noise.correlation_s and previous is not None:
                # frames in name order are the flight's; without timestamps, 1 s apart
                dt = (time_s - previous_time_s if time_s is not None and previous_time_s is not None
                      else 1.0)
                rho = math.exp(-max(dt, 0.0) / noise.correlation_s)
            try:
                noisy = add_pose_noise(doc, noise, frame_rng(seed, path.stem), previous, rho)
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(path, "ground_truth" if isinstance(exc, ValueError) else None,
                                 f"cannot add noise: {exc}") from None
            previous, previous_time_s = noisy["ground_truth"]["pose_errors"], time_s
            _keep_vessel_spec_reachable(noisy, path, out / "frames" / path.name)
            write_text_atomic(out / "frames" / path.name, strict_json(noisy, indent=1) + "\n")
            result.written.append(path.stem)
        except (HarborsightError, UnicodeDecodeError, OSError) as exc:
            result.skipped.append(f"{path}: {exc}" if not isinstance(exc, HarborsightError)
                                  else str(exc))
    return result


def _time_s(doc: dict[str, Any]) -> float | None:
    """A frame's ``timestamp`` in seconds, or None when it has none or it does not parse."""
    from harborsight.flight.timeline import iso_seconds

    stamp = doc.get("timestamp")
    if not isinstance(stamp, str):
        return None
    try:
        return iso_seconds(stamp)
    except (ValueError, HarborsightError):
        return None
