"""A receiver's own accuracy figures, as the one-sigma figures of ``harborsight.frame/1``.

A frame's ``position_sigma_m`` is one sigma per horizontal axis (east, north) in metres, its
``alt_sigma_m`` one sigma of the altitude in metres (:mod:`harborsight.geometry.sensor_sigmas`).
Logs state accuracy in three ways, each turned into those:

* a receiver's horizontal accuracy estimate: u-blox ``hAcc``, which PX4's driver logs as
  ``eph`` and ArduPilot as ``GPA.HAcc``. It is radial, ``sqrt(σ_lat² + σ_lon²)`` (u-blox
  forum, "How do I read the standard deviation of position error in UBX protocol?": the
  combined latitude/longitude deviation, a receiver's self-estimate; PX4's u-blox driver
  sets ``eph = hAcc · 1e-3``), so per axis it is divided by √2, as
  :data:`~harborsight.geometry.sensor_sigmas.GPS_CLASSES`' DRMS figures are;
* NMEA ``GST``: the standard deviations of the latitude and longitude errors in metres, one
  per axis already; the frame's single per-axis figure is their RMS,
  ``sqrt((σ_lat² + σ_lon²) / 2)`` (the same DRMS / √2);
* only a fix class (NMEA GGA quality, PX4 ``fix_type``, ArduPilot ``GPS.Status``): the class's
  horizontal RMS of ``GPS_CLASSES`` (RTK fixed: ``rtk``; RTK float and DGPS/SBAS: ``dgps``,
  float solutions being decimetres to a metre; a plain fix: ``standalone``), widened by the
  fix's HDOP where that is above 1 (the error is about HDOP times the range error, and a
  class figure is taken as its value under good geometry: HDOP never narrows it), per axis
  divided by √2. An HDOP that is not a number in (0, 50] (NMEA's 99.99 "no value",
  ArduPilot's 655.35 "unknown") is ignored: the class figure stands.

Figures that are not finite, not positive, or above 1000 m (the frame's limit) are missing.
"""

from __future__ import annotations

import math

import numpy as np

from harborsight.geometry.sensor_sigmas import GPS_CLASSES

#: the largest sigma (m) a frame takes (harborsight.frame's limit)
MAX_SIGMA_M = 1000.0
#: the largest HDOP taken as a value; above it a receiver means "unknown"
MAX_HDOP = 50.0

#: GPS_CLASSES name of each code of a fix class, by the log that writes it
PX4_FIX_CLASSES = {3: "standalone", 4: "dgps", 5: "dgps", 6: "rtk"}
ARDUPILOT_STATUS_CLASSES = {3: "standalone", 4: "dgps", 5: "dgps", 6: "rtk"}
GGA_QUALITY_CLASSES = {1: "standalone", 2: "dgps", 3: "standalone", 4: "rtk", 5: "dgps", 9: "dgps"}
#: the codes' meaning, for notes
FIX_NAMES = {3: "3-D fix", 4: "DGPS/SBAS", 5: "RTK float", 6: "RTK fixed"}
GGA_NAMES = {1: "GPS", 2: "DGPS", 3: "PPS", 4: "RTK fixed", 5: "RTK float", 9: "SBAS"}


def usable(values) -> np.ndarray:
    """``values`` as floats, NaN where not finite, not positive or above :data:`MAX_SIGMA_M`."""
    values = np.array(values, dtype=float, ndmin=1)
    with np.errstate(invalid="ignore"):
        values[~((values > 0) & (values <= MAX_SIGMA_M))] = np.nan
    return values


def per_axis_from_radial_m(radial_m) -> np.ndarray:
    """Per-axis sigma (m) of radial (DRMS) accuracy figures: ``radial / √2``; NaN where the
    figure is missing."""
    return usable(usable(radial_m) / math.sqrt(2.0))


def per_axis_from_gst_m(lat_sigma_m: float, lon_sigma_m: float) -> float:
    """One per-axis sigma (m) from GST's latitude and longitude sigmas: their RMS."""
    lat, lon = usable([lat_sigma_m, lon_sigma_m])
    return float(usable(math.sqrt((lat * lat + lon * lon) / 2.0))[0])


def per_axis_from_class_m(codes, hdops, classes: dict[int, str]) -> np.ndarray:
    """Per-axis sigma (m) of each fix from its class code (``classes`` maps codes to
    ``GPS_CLASSES`` names) and its HDOP (see the module docstring); NaN for a code no class
    has."""
    codes = np.array(codes, dtype=float, ndmin=1)
    hdops = np.broadcast_to(np.array(hdops, dtype=float, ndmin=1), codes.shape)
    out = np.full(codes.shape, np.nan)
    for i, (code, hdop) in enumerate(zip(codes, hdops, strict=True)):
        name = classes.get(int(code)) if np.isfinite(code) else None
        if name is None:
            continue
        widen = hdop if np.isfinite(hdop) and 1.0 < hdop <= MAX_HDOP else 1.0
        out[i] = GPS_CLASSES[name] * widen / math.sqrt(2.0)
    return usable(out)


def none_if_missing(values: np.ndarray | None) -> np.ndarray | None:
    """None for an array without a single finite value: the log gives no figure."""
    return None if values is None or not np.isfinite(values).any() else values


def count_codes(codes, names: dict[int, str]) -> str:
    """``"RTK fixed 12, 3-D fix 3"``: how many samples have each code, most first."""
    found, counts = np.unique(np.asarray(codes, dtype=int), return_counts=True)
    order = np.argsort(-counts, kind="stable")
    return ", ".join(f"{names.get(int(found[i]), f'code {int(found[i])}')} {int(counts[i])}"
                     for i in order)
