"""Autopilot flight logs: PX4 ULog (``.ulg``, read with pyulog) and ArduPilot DataFlash
(``.bin``, read with pymavlink's DFReader).

Both give the airframe's GPS position and its attitude (body FRD axes relative to NED), on the
autopilot's boot clock (``t_s`` = seconds since boot), and the UTC time of that clock from the
GPS: PX4's ``time_utc_usec``, ArduPilot's GPS week and milliseconds (``GWk``, ``GMS``; GPS time
runs ahead of UTC by the leap seconds: 15 s in 2009, 18 s since 2017).

Topics and messages read:

* PX4: ``vehicle_gps_position`` (``lat``/``lon`` in 1e-7 deg and ``alt`` in mm above mean sea
  level on older firmware; degrees and metres on newer) for position; ``vehicle_attitude``
  (quaternion ``q``, body FRD -> NED) for attitude; ``sensor_gps`` where the GPS topic has that
  name (PX4 1.14 on).
* ArduPilot: ``GPS`` (``Lat``, ``Lng`` in degrees, ``Alt`` in m above mean sea level, ``GWk``,
  ``GMS``), ``GPA`` (accuracy) and ``ATT`` (``Roll``, ``Pitch``, ``Yaw`` in degrees).

Altitude: the autopilot's estimator (EKF) altitude above mean sea level wherever the log has it
(PX4 ``vehicle_global_position.alt``, else ``vehicle_local_position`` ``ref_alt - z`` while
``z_global`` is set; ArduPilot ``POS.Alt``), interpolated to the GPS samples. The receiver's
own altitude is the noisiest height in the log: on the ground, PX4's sample log drifts
66.8 -> 63.0 m in 6 s (``epv`` 5-7 m) while the barometer moves 4 cm, and ArduPilot's
``GPS.Alt`` reads 4.4 m above ``POS.Alt``; every measured distance scales with the height
above the water. The raw GPS altitude is used, and noted, only where no estimate covers a
sample.

Accuracy (one sigma; conversions in :mod:`harborsight.telemetry.accuracy`; the track's notes
say which were used):

* horizontal, per axis: PX4's ``eph`` ("GPS horizontal position accuracy (metres)" in the
  uORB message definition; PX4's u-blox driver copies the receiver's radial ``hAcc``) divided
  by √2; ArduPilot's ``GPA.HAcc`` ("horizontal position accuracy", m; the receiver's own
  estimate, 0 where it gives none), matched to its GPS sample by ``TimeUS``, divided by √2.
  Where a sample has no such figure: the fix class (PX4 ``fix_type``, ArduPilot
  ``GPS.Status``: 6 RTK fixed, 5 RTK float, 4 DGPS, 3 3-D fix) widened by ``hdop``/``HDop``.
* altitude: the sigma of the altitude actually used. PX4's estimator states its own
  (``epv``, "standard deviation of vertical position error" of ``vehicle_global_position`` /
  ``vehicle_local_position``), relative to the estimator's origin, whose datum error shifts
  every frame alike; the receiver's ``epv`` (ArduPilot ``GPA.VAcc``) goes with the receiver's
  altitude only. ArduPilot logs no accuracy of ``POS.Alt``: where that is the altitude, the
  track has no altitude sigma (the receiver's VAcc would describe a different, noisier
  height).

On the real sample logs: PX4 eph 2.51-3.26 m (1.77-2.31 m per axis) and, its altitude being
the receiver's (``z_global`` is never set), epv 5.22-6.98 m; ArduPilot SITL HAcc 1.61 m
(1.14 m per axis) and no altitude sigma.

GPS samples are timed by when the receiver measured them (PX4's ``timestamp_sample``, where the
message has it) rather than when the driver published them, which is 0.1-0.2 s later on
u-blox receivers. ArduPilot logs only the arrival (``GPS.TimeUS``): its fixes are moved
back by the delay the autopilot itself assumes, where the log says it
(:func:`ardupilot_gps_lag_s`: ``GPS_DELAY_MS``, or the u-blox hardware of its startup
messages). Where a log has only the arrival and no such delay (older PX4 topics, another
receiver on ArduPilot) the track's notes say that the attitude is then read that much late
(:data:`RECEIVER_DELAY_NOTE`). A log cut short (power lost in flight, or only the first part copied) ends in
a partial record: it is read up to there, and the track's notes say so.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import sys
import tempfile
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from harborsight.errors import InputError
from harborsight.telemetry.accuracy import (
    ARDUPILOT_STATUS_CLASSES,
    FIX_NAMES,
    PX4_FIX_CLASSES,
    count_codes,
    none_if_missing,
    per_axis_from_class_m,
    per_axis_from_radial_m,
    usable,
)
from harborsight.telemetry.track import Track, interpolate_source, utc_from_epoch_s

GPS_EPOCH = datetime(1980, 1, 6, tzinfo=UTC)
#: GPS time minus UTC, from each UTC date on (IERS Bulletin C; none added since 2017-01-01).
GPS_MINUS_UTC_S = ((datetime(2009, 1, 1, tzinfo=UTC), 15), (datetime(2012, 7, 1, tzinfo=UTC), 16),
                   (datetime(2015, 7, 1, tzinfo=UTC), 17), (datetime(2017, 1, 1, tzinfo=UTC), 18))


#: said where a log times its GPS fixes by their arrival: the positions still meet the video
#: on time (UTC is matched to the same stamps), but attitude, logged on time, is then read
#: the receiver's delay later than it was (a helper's audit, twenty-sixth session: 0.2-0.4
#: degrees of yaw at the PX4 sample's turn rate, 0.2 m for a point 30 m off the centre)
RECEIVER_DELAY_NOTE = ("GPS fixes are timed by {stamp}, after the receiver's delay (0.1-0.2 s "
                       "on u-blox receivers; ArduPilot's GPS_DELAY_MS or EK3_GPS_DELAY says "
                       "what the autopilot assumes): the attitude is read that much after the "
                       "moment each frame was taken")


#: ArduPilot's own lag of a u-blox fix by the receiver's hardware version (MON-VER, which the
#: log's startup message "u-blox 1 HW: 00080000 SW: ..." names): 0.22 s for u-blox 5 and 6
#: and a generation it does not know, 0.12 s for 7, M8, F9, M9 and M10
#: (``AP_GPS_UBLOX::get_lag``). "00190000" is an F9 or M9 only with software "EXT CORE 1"
#: or "EXT CORE 4"; a moving-baseline receiver (GPS_TYPE 17 or 18) adds 0.04 s
UBLOX_LAG_S = {"00040005": 0.22, "00040007": 0.22, "00070000": 0.12, "00080000": 0.12,
               "00190000": 0.12, "000A0000": 0.12}
UBLOX_UNKNOWN_LAG_S = 0.22
UBLOX_MOVING_BASELINE_LAG_S = 0.04


def _first_ublox_version(messages: list[str]) -> tuple[str, str] | None:
    """(hardware, software) of the first receiver's startup message: "u-blox 1 HW: ...", or
    "u-blox 0 HW: ..." where older firmware numbered the receivers from 0."""
    versions = {}
    for message in messages:
        head, _, rest = message.partition(" HW: ")
        words = head.split()
        if len(words) == 2 and words[0] == "u-blox" and words[1] in ("0", "1") and rest:
            hardware, _, software = rest.partition(" SW: ")
            versions.setdefault(words[1], (hardware.strip().upper(), software.strip()))
    return versions.get("0") or versions.get("1")


def ardupilot_gps_lag_s(params: dict[str, float], messages: list[str]) -> tuple[float, str] | None:
    """How long after its fix ArduPilot takes the first receiver's position to arrive, as the
    autopilot itself assumes it: ``GPS_DELAY_MS`` (``GPS1_DELAY_MS`` from 4.6) where it is
    set above 0; else the u-blox driver's lag for the hardware the log's startup messages
    name (:data:`UBLOX_LAG_S`); else, in firmware whose EKF was given the delay,
    ``EK3_GPS_DELAY`` or ``EK2_GPS_DELAY``. ``(seconds, where from)``, or None where the log
    does not say (another receiver without a delay set)."""
    def set_delay(*names: str) -> tuple[float, str] | None:
        """The first of the parameters ``names`` set above 0, in seconds, and its name."""
        for name in names:
            delay_ms = params.get(name)
            if delay_ms is not None and delay_ms > 0:
                return delay_ms / 1000.0, f"{name} {delay_ms:g}"
        return None

    given = set_delay("GPS_DELAY_MS", "GPS1_DELAY_MS")
    if given is not None:
        return given
    version = _first_ublox_version(messages)
    if version is not None:
        hardware, software = version
        lag_s = UBLOX_LAG_S.get(hardware, UBLOX_UNKNOWN_LAG_S)
        if hardware == "00190000" and not software.startswith(("EXT CORE 1", "EXT CORE 4")):
            lag_s = UBLOX_UNKNOWN_LAG_S
        why = f"the u-blox driver's lag for hardware {hardware}"
        gps_type = params.get("GPS_TYPE", params.get("GPS1_TYPE"))
        if gps_type in (17.0, 18.0):
            lag_s += UBLOX_MOVING_BASELINE_LAG_S
            why += ", moving baseline"
        return round(lag_s, 3), why
    return set_delay("EK3_GPS_DELAY", "EK2_GPS_DELAY")


def utc_from_gps_time(gps_seconds: float) -> datetime:
    """UTC of a GPS time (seconds since the GPS epoch), from 2009 on: minus the leap seconds
    in force at that moment."""
    gps_time = GPS_EPOCH + timedelta(seconds=float(gps_seconds))
    if gps_time < GPS_MINUS_UTC_S[0][0]:
        raise ValueError(f"GPS time {gps_time:%Y-%m-%d} is before 2009: no leap-second entry")
    leap = [offset for since, offset in GPS_MINUS_UTC_S if gps_time - timedelta(seconds=offset) >= since]
    return gps_time - timedelta(seconds=leap[-1])


def ulog_partial_tail_bytes(path: Path) -> int:
    """Bytes at the end of a ULog that do not form a whole message (0 for an intact file).

    A ULog is a 16-byte header (magic ``ULog\\x01\\x12\\x35``, version, start time) followed by
    messages, each a 3-byte header (``uint16`` payload size, ``uint8`` type) and its payload;
    there is no end marker, so a torn last message is the only trace of a cut.
    """
    data = path.read_bytes()
    offset = 16
    while offset + 3 <= len(data):
        (size,) = struct.unpack_from("<H", data, offset)
        if offset + 3 + size > len(data):
            break
        offset += 3 + size
    return len(data) - offset


def _dataflash_partial_tail_bytes(log) -> int:
    """Bytes after the last whole record of a DataFlash log (0 if it ends with one): a torn
    record, or the first one or two bytes of a record header, which pymavlink does not index.
    From the message index pymavlink builds when it opens the file."""
    starts = [(offsets[-1], kind) for kind, offsets in enumerate(log.offsets) if offsets]
    if not starts:
        return 0
    last_start, kind = max(starts)
    last_end = last_start + log.formats[kind].len
    return log.data_len - last_start if last_end > log.data_len else log.data_len - last_end


def _px4_estimator_altitude(datasets: dict
                            ) -> tuple[np.ndarray, np.ndarray, str, np.ndarray | None]:
    """PX4's estimator altitude above mean sea level: (times s, altitudes m, what it is, the
    estimator's ``epv`` in m where the topic has it)."""
    glob = datasets.get("vehicle_global_position")
    if glob is not None and "alt" in glob and len(glob["timestamp"]):
        return (glob["timestamp"].astype(float) / 1e6, glob["alt"].astype(float),
                "EKF altitude above mean sea level (vehicle_global_position.alt)",
                glob["epv"].astype(float) if "epv" in glob else None)
    local = datasets.get("vehicle_local_position")
    if local is not None and {"z_global", "ref_alt", "z"} <= set(local):
        ok = local["z_global"].astype(bool)
        return (local["timestamp"][ok].astype(float) / 1e6,
                (local["ref_alt"][ok] - local["z"][ok]).astype(float),
                "EKF altitude above mean sea level (vehicle_local_position ref_alt - z)",
                local["epv"][ok].astype(float) if "epv" in local else None)
    return np.empty(0), np.empty(0), "", None


def _estimator_altitude(t_s: np.ndarray, gps_alt_m: np.ndarray, est_t_s: np.ndarray,
                        est_alt_m: np.ndarray, est_reference: str, notes: list[str],
                        est_sigma_m: np.ndarray | None = None,
                        gps_sigma_m: np.ndarray | None = None, edge_s: float = 0.0,
                        ) -> tuple[np.ndarray, str, np.ndarray]:
    """The estimator's altitude at the GPS sample times (linear interpolation, within its own
    time span only, or ``edge_s`` beyond its ends, where its end value holds), the raw GPS
    altitude where it does not reach; what the result is; and its one sigma (m), from the
    same source as each altitude: the estimator's ``est_sigma_m`` or the receiver's
    ``gps_sigma_m`` (NaN where that source states none)."""
    raw = "GPS receiver altitude above mean sea level"
    gps_sigma = np.full(len(t_s), np.nan) if gps_sigma_m is None else usable(gps_sigma_m)
    finite = np.isfinite(est_t_s) & np.isfinite(est_alt_m)
    est_t_s, est_alt_m = est_t_s[finite], est_alt_m[finite]
    if len(est_t_s) < 2:
        notes.append("no estimator altitude in the log: the GPS receiver's own altitude is "
                     "used, which can drift by metres in seconds")
        return gps_alt_m, raw, gps_sigma
    est_sigma = np.full(len(est_t_s), np.nan) if est_sigma_m is None else usable(
        est_sigma_m[finite])
    order = np.argsort(est_t_s, kind="stable")
    est_t_s, est_alt_m, est_sigma = est_t_s[order], est_alt_m[order], est_sigma[order]
    covered = (t_s >= est_t_s[0] - edge_s) & (t_s <= est_t_s[-1] + edge_s)
    # within edge_s past an end the end value holds; in a gap of the estimator's samples
    # there is none (track.interpolate_source): the receiver's altitude would jump from the
    # estimator's by metres, and a straight line across a dropout invents a climb
    inner, widest_s = interpolate_source(np.clip(t_s, est_t_s[0], est_t_s[-1]), est_t_s, est_alt_m)
    alt = np.where(covered, inner, gps_alt_m)
    stated = np.isfinite(est_sigma)
    sigma = np.where(covered, np.interp(t_s, est_t_s[stated], est_sigma[stated])
                     if stated.any() else np.nan, gps_sigma)
    sigma[covered & np.isnan(inner)] = np.nan
    if widest_s is not None:
        notes.append(f"{int((covered & np.isnan(inner)).sum())} GPS sample(s) fall in gaps of "
                     f"the estimator's altitude (up to {widest_s:.1f} s) and have no altitude: "
                     "frames there are skipped unless --max-gap-s bridges them")
    if not covered.all():
        notes.append(f"{int((~covered).sum())} GPS sample(s) outside the estimator's time "
                     "span keep the receiver's own altitude")
        return alt, f"{est_reference}; GPS receiver altitude outside its span", sigma
    return alt, est_reference, sigma


#: the largest altitude (m) and attitude angle (degrees) a log sample is taken with; a larger
#: one (a corrupt record, a byte flipped in the log) is taken as missing
MAX_LOG_ALTITUDE_M = 100_000.0
MAX_LOG_ANGLE_DEG = 720.0


def _possible_positions(t_s: np.ndarray, lat: np.ndarray, lon: np.ndarray,
                        notes: list[str]) -> np.ndarray:
    """Which GPS samples have a finite time and a position on the globe; the others come
    from corrupt records and are counted in ``notes``."""
    with np.errstate(invalid="ignore"):
        ok = (np.isfinite(t_s) & np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90)
              & (np.abs(lon) <= 180))
    if not ok.all():
        notes.append(f"{int((~ok).sum())} GPS sample(s) with no possible time or position "
                     "(not finite, or outside ±90°/±180°: corrupt records) skipped")
    return ok


def _position_sigma(figure_m: np.ndarray, codes: np.ndarray | None, hdop: np.ndarray | None,
                    classes: dict[int, str], keep: np.ndarray, notes: list[str],
                    figure_words: str, code_name: str) -> np.ndarray | None:
    """Per-axis position sigma (m) of the samples ``keep``: the receiver's own figure
    (``figure_m``, per axis already) where it states one, else its fix class widened by HDOP
    (:mod:`harborsight.telemetry.accuracy`); None where neither gives one. Says which in
    ``notes``, with the fix classes seen."""
    sigma = np.array(figure_m, dtype=float)[keep]
    stated = np.isfinite(sigma)
    classed = np.zeros(len(sigma), bool)
    hdop_missing = hdop is None
    if codes is not None:
        codes = np.asarray(codes, dtype=float)[keep]
        hdop = np.full(len(sigma), np.nan) if hdop is None else np.asarray(hdop, float)[keep]
        sigma[~stated] = per_axis_from_class_m(codes[~stated], hdop[~stated], classes)
        classed = ~stated & np.isfinite(sigma)
    if not (stated | classed).any():
        return None
    parts = [f"{figure_words} for {int(stated.sum())} of {len(sigma)} samples"] if stated.any() \
        else []
    if classed.any():
        parts.append(f"the {code_name} class for {int(classed.sum())}" + (
            " (no HDOP in the log)" if hdop_missing else ", widened by HDOP above 1"))
    if codes is not None and np.isfinite(codes).all():
        parts.append(f"{code_name}: {count_codes(codes, FIX_NAMES)}")
    notes.append("position_sigma_m (per axis): " + "; ".join(parts))
    return sigma


def _missing_if_absurd(values: np.ndarray, limit: float) -> np.ndarray:
    """``values`` with every non-finite one, or one larger than ``limit``, NaN (missing)."""
    values = np.array(values, dtype=float)
    with np.errstate(invalid="ignore"):
        values[~(np.abs(values) <= limit)] = np.nan
    return values


def _attitude_fields(t_s: np.ndarray | None, ypr_deg: np.ndarray | None) -> dict:
    """Track keyword arguments for a vehicle attitude on its own time axis (samples without
    a finite time dropped, absurd angles missing)."""
    if t_s is None:
        return {}
    timed = np.isfinite(t_s)
    t_s, ypr_deg = t_s[timed], _missing_if_absurd(ypr_deg[timed], MAX_LOG_ANGLE_DEG)
    return {"attitude_t_s": t_s, "yaw_deg": ypr_deg[:, 0], "pitch_deg": ypr_deg[:, 1],
            "roll_deg": ypr_deg[:, 2], "attitude_of": "vehicle"}


#: pyulog may read a damaged ULog's bytes again and again: it re-scans a corrupt stretch of
#: the definitions section a byte at a time, reading each would-be message whole, and a
#: fuzzed 37 kB log kept it in such a loop for good (pyulog 1.3). Reading more than this many
#: times the file's size (and a megabyte) stops it
ULOG_READ_LIMIT_FACTOR = 50


class _UlogReadLimitError(Exception):
    """pyulog read past :data:`ULOG_READ_LIMIT_FACTOR` times the file (not one of the
    exceptions pyulog catches while it re-scans)."""


class _BoundedFile:
    """A binary file for pyulog (``read``, ``seek``, ``tell``, ``close``) that raises
    :class:`_UlogReadLimitError` once ``limit`` bytes have been read in all."""

    def __init__(self, path: Path, limit: int) -> None:
        self._file = path.open("rb")
        self._left = limit

    def read(self, size: int = -1) -> bytes:
        data = self._file.read(size)
        self._left -= len(data)
        if self._left < 0:
            raise _UlogReadLimitError
        return data

    def seek(self, offset: int, whence: int = 0) -> int:
        return self._file.seek(offset, whence)

    def tell(self) -> int:
        return self._file.tell()

    def close(self) -> None:
        self._file.close()


def read_px4_ulog(path: str | Path) -> Track:
    """A PX4 ``.ulg`` log's GPS track with the vehicle attitude at each GPS sample."""
    from pyulog import ULog

    path = Path(path)
    topics = ["vehicle_gps_position", "sensor_gps", "vehicle_attitude",
              "vehicle_global_position", "vehicle_local_position"]
    try:
        size = path.stat().st_size
        bounded = _BoundedFile(path, ULOG_READ_LIMIT_FACTOR * size + 2 ** 20)
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    try:
        with contextlib.redirect_stdout(io.StringIO()):   # pyulog prints on corrupt files
            ulog = ULog(bounded, topics)
    except _UlogReadLimitError:
        raise InputError(path, None, "a damaged ULog: pyulog went over its bytes more than "
                         f"{ULOG_READ_LIMIT_FACTOR} times without getting through them "
                         "(a corrupt stretch it re-scans without end)") from None
    except Exception as exc:  # pyulog raises plain Exceptions and struct errors on foreign files
        raise InputError(path, None, f"not a readable PX4 ULog: {exc}") from None
    finally:
        bounded.close()     # (pyulog closes it only when it gets to the end)
    datasets = {d.name: d.data for d in ulog.data_list if d.multi_id == 0}
    gps_topic = "vehicle_gps_position" if "vehicle_gps_position" in datasets else "sensor_gps"
    gps = datasets.get(gps_topic)
    if gps is None:
        raise InputError(path, "vehicle_gps_position", "the log has no GPS topic "
                         "(vehicle_gps_position or sensor_gps)")
    notes = []
    if ulog.file_corruption:
        notes.append("the log is corrupt in places (pyulog skipped unreadable bytes)")
    tail = ulog_partial_tail_bytes(path)
    if tail:
        notes.append(f"the log ends in a partial message ({tail} bytes): it was cut short, "
                     "and is read up to there")
    t_s = gps["timestamp"].astype(float) / 1e6
    measured = "timestamp_sample" in gps and bool((gps["timestamp_sample"] > 0).all())
    if measured:
        t_s = gps["timestamp_sample"].astype(float) / 1e6     # the measurement, not the publish
    good = np.ones(len(t_s), bool)
    if "fix_type" in gps:
        # 3 3-D, 4 RTCM code differential, 5 RTK float, 6 RTK fixed; 8 is "extrapolated"
        # (sensor_gps.msg): a position the receiver did not measure
        extrapolated = gps["fix_type"] == 8
        good &= (gps["fix_type"] >= 3) & (gps["fix_type"] <= 6)
        if extrapolated.any():
            notes.append(f"{int(extrapolated.sum())} GPS sample(s) with fix_type 8 (extrapolated, "
                         "not a measured position) skipped")
        if (~good & ~extrapolated).any():
            notes.append(f"{int((~good & ~extrapolated).sum())} GPS sample(s) without a 3-D fix skipped")
    if "latitude_deg" in gps:                   # PX4 1.14 on: degrees and metres
        lat, lon = gps["latitude_deg"].astype(float), gps["longitude_deg"].astype(float)
        alt = gps["altitude_msl_m"].astype(float)
    else:                                       # older messages: 1e-7 deg and mm
        lat, lon = gps["lat"].astype(float) * 1e-7, gps["lon"].astype(float) * 1e-7
        alt = gps["alt"].astype(float) * 1e-3
    if not good.any():
        raise InputError(path, "fix_type", "the log has no GPS sample with a 3-D fix")
    good &= _possible_positions(t_s, lat, lon, notes)
    if not good.any():
        raise InputError(path, "vehicle_gps_position", "no GPS sample with a possible time and "
                         "position (the log is corrupt)")
    accuracy_notes: list[str] = []       # said last, after what was skipped
    position_sigma = _position_sigma(
        per_axis_from_radial_m(gps["eph"]) if "eph" in gps else np.full(len(t_s), np.nan),
        gps.get("fix_type"), gps.get("hdop"), PX4_FIX_CLASSES, good, accuracy_notes,
        f"{gps_topic}.eph / √2 (the receiver's horizontal accuracy, radial)", "fix_type")
    est_t_s, est_alt_m, est_reference, est_epv_m = _px4_estimator_altitude(datasets)
    alt, alt_reference, alt_sigma = _estimator_altitude(
        t_s, alt, est_t_s, est_alt_m, est_reference, notes, est_epv_m, gps.get("epv"))
    alt = _missing_if_absurd(alt, MAX_LOG_ALTITUDE_M)
    alt_sigma = none_if_missing(alt_sigma[good])
    if alt_sigma is not None:
        receiver = f"the receiver's {gps_topic}.epv (vertical accuracy)"
        topic = next((name for name in ("vehicle_global_position", "vehicle_local_position")
                      if est_reference and name in alt_reference), None)
        if topic is None:
            accuracy_notes.append(f"alt_sigma_m: {receiver}")
        elif alt_reference.endswith("its span"):
            accuracy_notes.append(f"alt_sigma_m: the estimator's {topic}.epv; {receiver} "
                                  "outside its span")
        else:
            accuracy_notes.append(f"alt_sigma_m: the estimator's {topic}.epv")
    utc_start = None
    if "time_utc_usec" in gps:
        utc_us = gps["time_utc_usec"].astype(float)
        synced = good & (utc_us > 0)
        # the boot time the UTC stamp belongs to is timestamp + timestamp_time_relative
        # (sensor_gps.msg): drivers that take the time from another message than the
        # position's set it, and then neither timestamp nor timestamp_sample is that time
        stamped_s = t_s
        if "timestamp_time_relative" in gps:
            stamped_s = (gps["timestamp"].astype(float)
                         + gps["timestamp_time_relative"].astype(float)) / 1e6
        if synced.any():
            offset_s = np.median(utc_us[synced] / 1e6 - stamped_s[synced])
            try:
                utc_start = utc_from_epoch_s(offset_s)
            except (ValueError, OverflowError, OSError):    # a corrupt time_utc_usec
                notes.append(f"no UTC: time_utc_usec puts the boot at {offset_s:.4g} s from "
                             "1970, not a time a flight can have")
    ypr = att_t_s = None
    att = datasets.get("vehicle_attitude")
    if att is not None and len(att["timestamp"]):
        quat_wxyz = np.column_stack([att[f"q[{i}]"] for i in range(4)]).astype(float)
        norm = np.linalg.norm(quat_wxyz, axis=1)
        rotates = np.isfinite(norm) & (norm > 1e-6)     # a zeroed record is no rotation
        ypr = np.full((len(quat_wxyz), 3), np.nan)
        if rotates.any():
            rotation = Rotation.from_quat(quat_wxyz[rotates][:, [1, 2, 3, 0]])  # x, y, z, w
            ypr[rotates] = rotation.as_euler("ZYX", degrees=True)    # R_NED<-B = Rz Ry Rx
        att_t_s = att["timestamp"].astype(float) / 1e6
    else:
        notes.append("no vehicle_attitude topic: no attitude")
    notes += accuracy_notes
    if not measured and att is not None:
        notes.append(RECEIVER_DELAY_NOTE.format(stamp=f"{gps_topic}.timestamp, when the driver "
                                                "published them (no timestamp_sample)"))
    return Track(
        source=path, kind="px4-ulog", t_s=t_s[good], lat_deg=lat[good], lon_deg=lon[good],
        alt_m=alt[good], alt_reference=alt_reference,
        position_sigma_m=position_sigma, alt_sigma_m=alt_sigma,
        **_attitude_fields(att_t_s, ypr), utc_start=utc_start,
        clock="seconds since the autopilot booted", notes=notes,
    )


@contextlib.contextmanager
def _captured_output(sink: io.StringIO):
    """Everything written to stdout and stderr inside the block, Python's and C's alike
    (pymavlink's Cython indexer prints a line per bad header with C stdio), goes to ``sink``
    instead of the terminal."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = {fd: os.dup(fd) for fd in (1, 2)}
    with tempfile.TemporaryFile(mode="w+b") as spool:
        try:
            for fd in saved:
                os.dup2(spool.fileno(), fd)
            with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
                yield sink
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, copy in saved.items():
                os.dup2(copy, fd)
                os.close(copy)
            spool.seek(0)
            sink.write(spool.read().decode("utf-8", "replace"))


def read_ardupilot_bin(path: str | Path) -> Track:
    """An ArduPilot DataFlash ``.bin`` log's GPS track with ``ATT`` attitude at each sample."""
    from pymavlink import DFReader

    path = Path(path)
    noise = io.StringIO()        # pymavlink prints a line per bad header on foreign files
    try:
        with _captured_output(noise):
            log = DFReader.DFReader_binary(str(path), zero_time_base=False)
    except Exception as exc:  # DFReader raises assorted errors on foreign files
        raise InputError(path, None, f"not a readable ArduPilot DataFlash log: {exc}") from None
    gps_rows, att_rows, pos_rows, unfixed, other_instances = [], [], [], 0, 0
    accuracy: dict[int, tuple[float, float]] = {}   # GPA by TimeUS: HAcc, VAcc (m)
    params: dict[str, float] = {}
    texts: list[str] = []
    with _captured_output(noise):
        while True:
            try:
                message = log.recv_match(type=["GPS", "ATT", "POS", "GPA", "PARM", "MSG"])
            except Exception as exc:  # a torn record at the end of a log cut by power loss
                raise InputError(path, None, f"unreadable record after {len(gps_rows)} GPS "
                                 f"sample(s): {exc}") from None
            if message is None:
                break
            try:
                if message.get_type() == "GPS":
                    if getattr(message, "I", 0) != 0:   # 4.1 on: every receiver logs as GPS
                        other_instances += 1
                        continue
                    if not 3 <= getattr(message, "Status", 3) <= 6:   # AP_GPS: 3 3-D ... 6 RTK fixed
                        unfixed += 1
                        continue
                    gps_rows.append((message.TimeUS / 1e6, message.Lat, message.Lng, message.Alt,
                                     message.GWk, message.GMS, getattr(message, "HDop", np.nan),
                                     getattr(message, "Status", 3), message.TimeUS))
                elif message.get_type() == "GPA":       # logged with its GPS message's TimeUS
                    if getattr(message, "I", 0) == 0:
                        accuracy[message.TimeUS] = (getattr(message, "HAcc", np.nan),
                                                    getattr(message, "VAcc", np.nan))
                elif message.get_type() == "POS":
                    pos_rows.append((message.TimeUS / 1e6, message.Alt))
                elif message.get_type() == "PARM":
                    params[str(message.Name)] = float(message.Value)
                elif message.get_type() == "MSG":
                    texts.append(str(message.Message))
                else:
                    att_rows.append((message.TimeUS / 1e6, message.Yaw, message.Pitch,
                                     message.Roll))
            except AttributeError as exc:     # ArduPilot before 3.3: TimeMS, Week, T
                raise InputError(path, message.get_type(), f"unsupported (older) DataFlash "
                                 f"format: {exc}") from None
    if not gps_rows:
        bad_headers = noise.getvalue().count("bad header")
        if bad_headers and not (att_rows or pos_rows or unfixed or other_instances):
            raise InputError(path, None, f"not an ArduPilot DataFlash log: no GPS, ATT or POS "
                             f"record, {bad_headers} unreadable record header(s)")
        raise InputError(path, "GPS", "the log has no GPS message with a 3-D fix")
    gps = np.array(gps_rows, dtype=float)
    notes = [f"{unfixed} GPS sample(s) without a 3-D fix skipped"] if unfixed else []
    tail = _dataflash_partial_tail_bytes(log)
    if tail:
        notes.append(f"the log ends in a partial record ({tail} bytes): it was cut short, "
                     "and is read up to there")
    if other_instances:
        notes.append(f"{other_instances} sample(s) of other GPS receivers (I > 0) left out")
    gps = gps[_possible_positions(gps[:, 0], gps[:, 1], gps[:, 2], notes)]
    if not len(gps):
        raise InputError(path, "GPS", "no GPS sample with a possible time and position (the "
                         "log is corrupt)")
    # GPS.TimeUS is when the fix was logged, on its arrival; the fix is that much older
    lag = ardupilot_gps_lag_s(params, texts)
    lag_s = lag[0] if lag else 0.0
    t_s = gps[:, 0] - lag_s
    hacc_m, vacc_m = np.array([accuracy.get(int(time_us), (np.nan, np.nan))
                               for time_us in gps[:, 8]], dtype=float).reshape(-1, 2).T
    accuracy_notes: list[str] = []       # said last, after what was skipped
    position_sigma = _position_sigma(
        per_axis_from_radial_m(hacc_m), gps[:, 7], gps[:, 6], ARDUPILOT_STATUS_CLASSES,
        np.ones(len(gps), bool), accuracy_notes,
        "GPA.HAcc / √2 (the receiver's horizontal accuracy, radial)", "GPS Status")
    pos = np.array(pos_rows, dtype=float).reshape(-1, 2)
    # a fix logged inside POS's span but dated up to the lag before it holds POS's first value
    alt, alt_reference, alt_sigma = _estimator_altitude(
        t_s, gps[:, 3], pos[:, 0], pos[:, 1], "EKF altitude above mean sea level (POS.Alt)",
        notes, None, vacc_m, edge_s=lag_s)
    alt = _missing_if_absurd(alt, MAX_LOG_ALTITUDE_M)
    alt_sigma = none_if_missing(alt_sigma)
    if alt_sigma is not None:
        accuracy_notes.append("alt_sigma_m: GPA.VAcc (the receiver's vertical accuracy) where "
                              "the receiver's own altitude is used")
    if "POS.Alt" in alt_reference and np.isfinite(usable(vacc_m)).any():
        accuracy_notes.append("alt_sigma_m: none for the EKF altitude (POS.Alt): the log states "
                              "no accuracy for it, and GPA.VAcc is the receiver's altitude's")
    utc_start = None
    weeks, ms = gps[:, 4], gps[:, 5]
    if (weeks > 0).any():
        gps_time_s = weeks * 7 * 86400 + ms / 1000.0
        boot_gps_s = float(np.median(gps_time_s[weeks > 0] - t_s[weeks > 0]))
        try:
            utc_start = utc_from_gps_time(boot_gps_s)
        except ValueError as exc:
            notes.append(f"no UTC: {exc}")
    att = np.array(att_rows, dtype=float) if att_rows else None
    if att is None:
        notes.append("no ATT messages: no attitude")
    notes += accuracy_notes
    if lag is not None:
        notes.append(f"GPS fixes are timed by GPS.TimeUS less {lag[0]:g} s, the receiver's "
                     f"delay ArduPilot assumes ({lag[1]})")
    elif att is not None:
        notes.append(RECEIVER_DELAY_NOTE.format(stamp="GPS.TimeUS, when they were logged"))
    return Track(
        source=path, kind="ardupilot-bin", t_s=t_s, lat_deg=gps[:, 1], lon_deg=gps[:, 2],
        alt_m=alt, alt_reference=alt_reference,
        position_sigma_m=position_sigma, alt_sigma_m=alt_sigma,
        **_attitude_fields(None if att is None else att[:, 0], None if att is None else att[:, 1:]),
        utc_start=utc_start,
        clock="seconds since the autopilot booted", notes=notes,
    )
