"""DJI video telemetry: the ``.SRT`` subtitle file a DJI drone records beside each video.

Each subtitle block carries one sample; its start timecode is the video time it belongs to.
Firmware families write different text (all seen in real files):

* ``[latitude: 41.424724] [longitude: 2.234156] [rel_alt: 1.3 abs_alt: 132.8]`` or
  ``[altitude: 117.0]`` (Mini 3/4, Air 2, Air 2S, Mavic 3, ...); Mavic 2 / Air 2 firmware spell
  ``[longtitude : ...]``, and their Mavic 2 style files have no timecodes at all;
* ``GPS(149.0251,-20.2533,16) BAROMETER:1.9`` (Mavic Pro, P4; ``Hb:`` on older firmware) and
  ``GPS (8.2090, 47.4692, 18), ... H 45.60m`` (P4P, P4 RTK, Mavic Mini): **longitude first**,
  then latitude, then the satellite count, as in DJI's ``HOME(...)`` fields (the Mavic Pro
  file and the Mavic 2 style file of the same flight, which labels its fields, agree);
* ``GPS(36.6146,-6.1120,0.0M) BAROMETER:0.3M`` (DJI Pilot, Matrice 300): the third value is an
  altitude in metres, and this form is **latitude first** (Cádiz Bay here; other published
  samples of it, e.g. ``GPS(37.8757,-122.3061,0.0M)``, only make sense that way);
* ``G.PRY (pitch°, roll°, yaw°)``: the gimbal's attitude (P4 RTK); ``F.PRY`` is the
  airframe's. Enterprise models of the Mavic 3 generation write the gimbal as
  ``[gb_yaw: -137.7 gb_pitch: -45.0 gb_roll: 0.0]`` (absolute angles, degrees).

Altitudes: ``rel_alt``, ``BAROMETER``, ``Hb`` and ``H`` are barometric heights above the
take-off point; ``abs_alt`` is above mean sea level. A ``[altitude: ...]`` field's datum is not
documented by DJI; the track says so and the operator sets ``water_level_m`` accordingly.

Date lines are the drone's local time, with no zone: they become UTC only with a given
``utc_offset_h``. The local time at t = 0 is the median over all dated blocks of date minus
block time; older firmware writes whole seconds (truncated), and then it is their mean plus
0.5 s, good to a few tenths of a second instead of up to 1 s early from the first block alone.

Accuracy: none of these families states any. No RTK flag, standard deviation or DOP field
appears in the real files, the P4 RTK's and the Matrice 300's included (the P4 RTK's
``GPS (lon, lat, 15)`` ends in the satellite count, the Matrice 300's ``GPS(lat, lon, 0.0M)``
in an altitude); DJI documents ``RtkFlag`` and ``RtkStdLon``/``RtkStdLat``/``RtkStdHgt`` for
its photos' XMP metadata, not for the SRT. The track has no accuracy figures, and the sensor
defaults (``harborsight.geometry.sensor_sigmas``) apply to its frames.

Latitude/longitude printed with four decimals (Mavic Pro, Mavic Mini, Matrice 300 files) are
steps of 11 m north-south: the track's notes say so, since the drone's position places the
vessel in the image.
"""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.telemetry.track import Track

_NUMBER = r"[-+]?\d+(?:\.\d+)?"
# hours of at most 6 digits: a longer run is not a timecode (and 400 digits overflow a float)
_TIMECODE = re.compile(r"^(\d{1,6}):(\d{2}):(\d{2})[,.](\d{3})\s*-->\s*(\d{1,6}):(\d{2}):(\d{2})[,.](\d{3})")
_BRACKET = re.compile(r"\b(latitude|longitude|longtitude|rel_alt|abs_alt|altitude|focal_len)\s*:\s*("
                      + _NUMBER + ")", re.IGNORECASE)
_GPS = re.compile(r"\bGPS\s*\(\s*(" + _NUMBER + r")\s*,\s*(" + _NUMBER + r")\s*(?:,\s*(" + _NUMBER
                  + r")\s*(M)?)?\s*\)", re.IGNORECASE)
_BARO = re.compile(r"\b(?:BAROMETER\s*:\s*|Hb\s*:\s*|H\s+)(" + _NUMBER + r")\s*m?\b", re.IGNORECASE)
# between a number and its comma: a degree sign, or its mis-decoded bytes (cp1252 files)
_UNIT = r"[^\d,()+-]*"
_PRY = re.compile(r"\b([GF])\.PRY\s*\(\s*(" + _NUMBER + ")" + _UNIT + r",\s*(" + _NUMBER + ")" + _UNIT
                  + r",\s*(" + _NUMBER + ")" + _UNIT + r"\)", re.IGNORECASE)
# digital zoom: "[dzoom_ratio: 20000, delta:0]" (Mini 3/4, Air 2S, Mavic 3: ten-thousandths),
# "[dzoom_ratio: 2.00]" (enterprise thermal files), "DZOOM 2.000" (Mini 2, Mini SE)
_DZOOM = re.compile(r"\b(?:dzoom_ratio\s*:\s*|DZOOM\s*:?\s*)(" + _NUMBER + ")", re.IGNORECASE)
_GIMBAL_ANGLES = re.compile(r"\bgb_(yaw|pitch|roll)\s*:\s*(" + _NUMBER + ")", re.IGNORECASE)
_DATE = re.compile(r"\b(\d{4})[-.](\d{1,2})[-.](\d{1,2})\s+(\d{1,2}):(\d{2}):(\d{2})"
                   r"(?:[,.](\d{3})(?:[,.](\d{3}))?)?")
_TAGS = re.compile(r"<[^>]*>")


def _blocks(text: str) -> list[tuple[int, list[str]]]:
    """Subtitle blocks with the 1-based line number of their first line: separated by blank
    lines, and also by a timecode line in a block that already has one (files whose blank
    lines were lost, e.g. by an editor; the block's counter line before it moves along)."""
    blocks, current, start = [], [], 0
    for number, line in enumerate(text.splitlines(), start=1):
        line = _TAGS.sub("", line).strip()
        if not line:
            if current:
                blocks.append((start, current))
            current = []
            continue
        if _TIMECODE.match(line) and any(_TIMECODE.match(seen) for seen in current):
            counter = [current.pop()] if current[-1].isdigit() else []
            if current:
                blocks.append((start, current))
            current, start = counter, number - len(counter)
        if not current:
            start = number
        current.append(line)
    if current:
        blocks.append((start, current))
    return blocks


def _parse_date(match: re.Match) -> datetime | None:
    """The date line's time, or None for an impossible date (month 13, ...)."""
    year, month, day, hour, minute, second, ms, us = match.groups()
    micro = int(ms or 0) * 1000 + int(us or 0)
    try:
        return datetime(int(year), int(month), int(day), int(hour), int(minute), int(second), micro)
    except ValueError:
        return None


def _all_finite(row: dict) -> bool:
    """Whether every number a block gave (its fields and gimbal angles) is finite."""
    values = [v for v in row.values() if isinstance(v, float)]
    values += list(row.get("gimbal", ()))
    return bool(np.isfinite(values).all()) if values else True


def _lines(numbers: list[int]) -> str:
    shown = ", ".join(str(n) for n in numbers[:5]) + (", ..." if len(numbers) > 5 else "")
    return f"line{'s' if len(numbers) > 1 else ''} {shown}"


def _local_time_at_zero(rows: list[dict], t_s: np.ndarray) -> datetime | None:
    """The date lines' local time at t = 0 (module docstring), None without date lines."""
    dated = [(r["date"], float(t)) for r, t in zip(rows, t_s, strict=True) if "date" in r]
    if not dated:
        return None
    reference = dated[0][0]
    offsets_s = np.array([(date - reference).total_seconds() - t for date, t in dated])
    if any(date.microsecond for date, _ in dated):
        shift_s = float(np.median(offsets_s))
    else:                   # each date is floor(true time): true offset in [o, o + 1)
        shift_s = float(np.mean(offsets_s)) + 0.5
    return reference + timedelta(seconds=shift_s)


def _utc_start(local_start: datetime, utc_offset_h: float, duration_s: float, path: Path
               ) -> datetime:
    """The UTC time at t = 0 from the local one; :class:`InputError` on the field ``date``
    where it, or the time of the file's last sample, falls outside the years 1 to 9999 that
    a time can take (the date lines of a drone whose clock was never set, say)."""
    try:
        utc_start = (local_start - timedelta(hours=utc_offset_h)).replace(tzinfo=UTC)
        utc_start + timedelta(seconds=duration_s)
    except OverflowError:
        raise InputError(path, "date", f"the date lines ({local_start.isoformat()} local time at "
                         f"t = 0, UTC offset {utc_offset_h:+g} h) put the samples before the year "
                         "1 or after 9999 in UTC: not a time a flight can have") from None
    return utc_start


def _coarse_position_notes(rows: list[dict]) -> list[str]:
    """A note when the file prints latitude with four decimals or fewer (11 m steps)."""
    lat = np.array([r["latitude"] for r in rows]) * 1e4
    if len(lat) < 2 or not np.allclose(lat, np.round(lat), rtol=0.0, atol=1e-3):
        return []
    return ["positions are printed to 1e-4 degree (steps of 11 m north-south): the drone's "
            "position, and so where the vessel is drawn in the image, is that coarse"]


def read_dji_srt(path: str | Path, utc_offset_h: float | None = None) -> Track:
    """Read a DJI ``.SRT`` file into a :class:`Track`; blocks without a position are skipped
    and counted in ``notes``. Raises :class:`InputError` when no block has one."""
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig", errors="replace")
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    rows: list[dict] = []
    skipped: list[int] = []
    out_of_range: list[int] = []
    bad_dates: list[int] = []
    too_large: list[int] = []
    blocks = _blocks(text)
    # a file cut inside its last line (a copy interrupted, a card pulled): its last field may
    # be cut too, and "[altitude: 117.0" cut to "[altitude: 11" reads 11 m. Files saved
    # without a final newline are common, so a missing newline alone is no proof: the last
    # block must also be shorter than the one before it (fewer lines, or a last line more
    # than 3 characters shorter: digits lost, not just a rounding width)
    torn: list[int] = []
    if len(blocks) >= 2 and not text.rstrip("\x00").endswith(("\n", "\r")):
        last, before = blocks[-1][1], blocks[-2][1]
        if len(last) < len(before) or len(last[-1]) < len(before[-1]) - 3:
            torn.append(blocks[-1][0])
            blocks = blocks[:-1]
    focal_in_mm = False
    for line_number, lines in blocks:
        row: dict = {"line": line_number}
        body = []
        for line in lines:
            if (m := _TIMECODE.match(line)) is not None:
                h, mi, s, ms = (int(g) for g in m.groups()[:4])
                row["video_s"] = h * 3600 + mi * 60 + s + ms / 1000.0
            elif line.isdigit() and "video_s" not in row and not body:
                continue                                   # the block's counter
            else:
                body.append(line)
        content = " ".join(body)
        for key, value in _BRACKET.findall(content):
            key = key.lower().replace("longtitude", "longitude")
            row[key] = float(value)
            if key == "focal_len" and "." in value:
                focal_in_mm = True
        if (m := _GPS.search(content)) is not None:
            first, second = float(m.group(1)), float(m.group(2))
            if m.group(4) and m.group(3) is not None:       # (lat, lon, altM): DJI Pilot
                row.setdefault("latitude", first)
                row.setdefault("longitude", second)
                row["gps_alt"] = float(m.group(3))
            else:                                           # (lon, lat, satellites)
                row.setdefault("longitude", first)
                row.setdefault("latitude", second)
        if (m := _BARO.search(content)) is not None:
            row["baro_alt"] = float(m.group(1))
        if (m := _DZOOM.search(content)) is not None:
            ratio = float(m.group(1))
            if "." not in m.group(1) and ratio >= 100:      # ten-thousandths: 10000 is 1x
                ratio /= 10000.0
            if ratio > 0:                                   # a 0 states nothing
                row["digital_zoom"] = ratio
        for which, pitch, roll, yaw in _PRY.findall(content):
            if which.upper() == "G":
                row["gimbal"] = (float(yaw), float(pitch), float(roll))
        angles = {k.lower(): float(v) for k, v in _GIMBAL_ANGLES.findall(content)}
        if "gimbal" not in row and len(angles) == 3:
            row["gimbal"] = (angles["yaw"], angles["pitch"], angles["roll"])
        if (m := _DATE.search(content)) is not None:
            if (when := _parse_date(m)) is not None:
                row["date"] = when
            else:
                bad_dates.append(line_number)
        if not _all_finite(row):       # a number of hundreds of digits reads as infinity
            too_large.append(line_number)
            continue
        lat, lon = row.get("latitude"), row.get("longitude")
        if lat is None or lon is None or (lat, lon) == (0.0, 0.0):
            skipped.append(line_number)
        elif not (-90 <= lat <= 90 and -180 <= lon <= 180):
            out_of_range.append(line_number)
        else:
            rows.append(row)
    if len(rows) >= 3:
        # cut at a line end inside the last block: it lacks fields every other block has
        common = set.intersection(*(set(r) for r in rows[:-1]))
        if not common <= set(rows[-1]):
            torn.append(rows.pop()["line"])
    if out_of_range and not rows:
        raise InputError(path, f"line {out_of_range[0]}", "position outside ±90° latitude / "
                         "±180° longitude: not a DJI GPS field this reader knows")
    if not rows:
        raise InputError(path, None, "no DJI telemetry block with a position (latitude/longitude "
                         "or GPS(...)); is this a DJI .SRT file?")

    without_clock: list[int] = []
    notes_clock: list[str] = []
    if any("video_s" in r for r in rows):
        without_clock = [r["line"] for r in rows if "video_s" not in r]
        rows = [r for r in rows if "video_s" in r]
        t_s = np.array([r["video_s"] for r in rows])
        clock = "video time (subtitle start timecodes)"
    elif any("date" in r for r in rows):
        without_clock = [r["line"] for r in rows if "date" not in r]
        rows = [r for r in rows if "date" in r]
        first = rows[0]["date"]
        t_s = np.array([(r["date"] - first).total_seconds() for r in rows])
        clock = "seconds since the first date line (the file has no timecodes)"
        notes_clock = ["no timecodes: the video is taken to start at the first date line"
                       + (", to within 1 s (whole-second dates)"
                          if not any(r["date"].microsecond for r in rows) else "")]
    else:
        raise InputError(path, None, "no block has a timecode or a date line: no time for the "
                         "samples")

    partial: list[str] = []

    def column(key: str, width: int = 0) -> np.ndarray | None:
        """A quantity over all rows, NaN where a block lacks it; None where none has it."""
        have = [key in r for r in rows]
        if not any(have):
            return None
        if not all(have):
            partial.append(f"{have.count(False)} block(s) without {key}")
        blank = np.full(width, np.nan) if width else np.nan
        return np.array([r.get(key, blank) for r in rows], dtype=float)

    altitude, reference, altitude_notes = None, None, []
    placeholder = [r["gps_alt"] for r in rows if "gps_alt" in r]
    if placeholder and not any(placeholder):
        # DJI Pilot writes GPS(lat, lon, 0.0M) in every block while its BAROMETER climbs (a
        # Matrice 300's 381 blocks): a zero there is no altitude
        for r in rows:
            r.pop("gps_alt", None)
        altitude_notes.append("GPS(lat, lon, 0.0M): the altitude in the GPS field is 0.0 in every "
                           "block, a placeholder, and is not read")
    for key, words in (("rel_alt", "barometric height above the take-off point (rel_alt)"),
                       ("baro_alt", "barometric height above the take-off point"),
                       ("abs_alt", "above mean sea level (abs_alt)"),
                       ("altitude", "DJI 'altitude' field (datum not documented by DJI)"),
                       ("gps_alt", "GPS altitude")):
        if any(key in r for r in rows):
            altitude, reference = column(key), words
            break
    gimbal = column("gimbal", 3)
    # the 35 mm equivalent focal length, one unit for the whole file: whole tenths of a
    # millimetre in the files of the Air 2 and Air 2S ("240" is 24 mm), millimetres where
    # the file writes decimals ("24.00"); a 10x zoom's "240.00" is 240 mm
    focal_len = column("focal_len")
    if focal_len is not None and not focal_in_mm:
        focal_len = focal_len / 10.0
    digital_zoom = column("digital_zoom")

    notes = [f"{len(lines)} block(s) {what} (" + _lines(lines) + ")" for lines, what in (
        (skipped, "without a position skipped"),
        (out_of_range, "with a position outside ±90°/±180° skipped"),
        (without_clock, "without the file's clock (timecode or date) skipped"),
        (bad_dates, "with an impossible date line (date ignored)"),
        (too_large, "with a number too large to be a reading skipped"),
        (torn, "cut short at the end of the file left out"),
    ) if lines] + partial + notes_clock + altitude_notes + _coarse_position_notes(rows)
    if digital_zoom is not None and np.nanmax(np.abs(digital_zoom - 1.0), initial=0.0) > 1e-3:
        zoomed = int((np.abs(digital_zoom - 1.0) > 1e-3).sum())
        notes.append(f"digital zoom in {zoomed} block(s), up to {np.nanmax(digital_zoom):g}x: "
                     "a centre crop of the sensor, so those frames' intrinsics are the camera's "
                     "scaled by it about the image centre")
    utc_start = None
    try:
        local_start = _local_time_at_zero(rows, t_s)
    except OverflowError:
        raise InputError(path, "date", "the date lines put the video's start before the year 1 "
                         "or after 9999: not a time a flight can have") from None
    if local_start is not None:
        if utc_offset_h is not None:
            utc_start = _utc_start(local_start, utc_offset_h, float(t_s.max()), path)
        else:
            notes.append(f"date lines are local time ({local_start.isoformat()} at t = 0); "
                         "give the UTC offset to place them in UTC")
    return Track(
        source=path, kind="dji-srt", t_s=t_s,
        lat_deg=np.array([r["latitude"] for r in rows]),
        lon_deg=np.array([r["longitude"] for r in rows]),
        alt_m=altitude, alt_reference=reference,
        yaw_deg=None if gimbal is None else gimbal[:, 0],
        pitch_deg=None if gimbal is None else gimbal[:, 1],
        roll_deg=None if gimbal is None else gimbal[:, 2],
        attitude_of=None if gimbal is None else "gimbal",
        focal_35mm_mm=focal_len, digital_zoom=digital_zoom, utc_start=utc_start, clock=clock,
        notes=notes,
    )
