"""The vessel's own track: position and true heading over time, from the ship's NMEA 0183 feed
(read with pynmea2, sentence by sentence by :class:`harborsight.telemetry.nmea.NmeaDecoder`,
which the live feed shares) or from a CSV.

NMEA: ``RMC`` gives UTC date, time and position; ``GGA`` time and position (its date comes from
the last ``RMC`` or ``ZDA``); ``HDT`` and ``THS`` the true heading; ``HDG`` a magnetic heading that becomes
true with the deviation and variation it carries; ``HDM``, and an ``HDG`` without variation, a
magnetic heading made true with the World Magnetic Model's declination at the last fix
(:mod:`harborsight.telemetry.declination`). Where a feed has both, true headings (HDT, THS, HDG with
variation) are used and the magnetic ones are left out.
Heading sentences have no time: those between two fixes are spread evenly over that interval
(:func:`_heading_times`). The heading at each position fix is then interpolated (on unwrapped
angles) from heading samples no more than ``max_heading_gap_s`` away. A fix whose time of day
is over 12 h before the previous one's is in the next day (a GGA after midnight, before the
next RMC/ZDA brings the date). Course over ground (``RMC``/``VTG``) is never used as heading: a
vessel berthing moves sideways.

Accuracy (NMEA; conversions in :mod:`harborsight.telemetry.accuracy`): a fix's
``position_sigma_m`` (one sigma per horizontal axis, m) comes from the ``GST`` sentence of its
epoch, matched by GST's time field (the "UTC time of the GGA or GNS fix associated with this
sentence", as pynmea2 documents it): the RMS of its latitude and longitude error standard
deviations (metres, one per axis). A fix without a GST takes its GGA quality's class (4 RTK
fixed: ``rtk``; 5 RTK float and 2 DGPS: ``dgps``; 1 GPS and 3 PPS: ``standalone``; horizontal
RMS per receiver of ``GPS_CLASSES``), widened by the GGA's HDOP above 1, divided by √2; a fix
from RMC alone, without a GST, has none. The heading sentences read (HDT, THS, HDG, HDM) state no
accuracy: the track has no heading sigma.

Only measured fixes and headings are used; the rest are skipped and counted in the notes: an
RMC with status V, or with a mode indicator (NMEA 2.3 on) of E (estimated, dead reckoning),
M (manual input), S (simulator) or N (not valid); a GGA of quality 0 (invalid), 6 (estimated),
7 (manual input) or 8 (simulator), or of a code the standard does not define (9, SBAS in
some receivers' manuals, is read as DGPS); a THS (true heading and status, NMEA 0183 v3) whose
mode is not A (autonomous): E estimated, M manual, S simulator, V not valid.

CSV: a header line, then one row per sample, with columns ``time`` (ISO 8601 with a zone, e.g.
``2026-05-01T12:00:00.25Z``), ``lat``, ``lon`` (degrees) and ``heading_deg`` (true, clockwise
from north), or instead ``heading_mag_deg`` (magnetic, deviation already applied: made true
with the WMM declination of each row). Optional columns carry the receivers' accuracy, as the
frame metadata does: ``position_sigma_m`` (one sigma per horizontal axis, m) and
``heading_sigma_deg`` (one sigma, degrees); an empty cell is a row without one, a value that
is not a number above 0 and at most 1000 makes the row unreadable (skipped and noted).
"""

from __future__ import annotations

import csv
import math
from datetime import UTC, datetime, time
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.telemetry.accuracy import (
    GGA_NAMES,
    GGA_QUALITY_CLASSES,
    MAX_SIGMA_M,
    count_codes,
    none_if_missing,
    per_axis_from_class_m,
)
from harborsight.telemetry.declination import (
    decimal_year,
    magnetic_declination_deg,
    wmm_model_name,
)
from harborsight.telemetry.nmea import Fix, Gst, Heading, NmeaDecoder, RateOfTurn
from harborsight.telemetry.track import POSITION_GAP_DEAD_RECKON_S, Track


def read_vessel_track(path: str | Path, max_heading_gap_s: float = 2.0, *, mmsi: int | None = None,
                      allow_cog_heading: bool = False) -> Track:
    """CSV (``.csv``) by extension; else AIS (:mod:`harborsight.telemetry.ais`: ``.ais``, or
    AIVDM/AIVDO sentences and no RMC/GGA in the file's first 64 kB) for the vessel ``mmsi``;
    else NMEA 0183."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return read_vessel_csv(path)
    if is_ais_log(path):
        from harborsight.telemetry.ais import read_ais_track

        return read_ais_track(path, mmsi, allow_cog_heading)
    if mmsi is not None:
        raise InputError(path, "--mmsi", "an MMSI picks a vessel in an AIS file; this is not one "
                         "(no AIVDM/AIVDO sentences)")
    return read_vessel_nmea(path, max_heading_gap_s)


def is_ais_log(path: Path) -> bool:
    """Whether ``path`` holds AIS sentences (AIVDM/AIVDO) rather than a receiver's fixes: an
    ``.ais`` file, or one whose head has AIS sentences and no RMC or GGA."""
    if path.suffix.lower() == ".ais":
        return True
    try:
        with path.open("rb") as handle:
            head = handle.read(65536).decode("ascii", errors="replace")
    except OSError:
        return False                  # the NMEA reader says why it cannot read it
    has_ais = any(tag in head for tag in ("!AIVDM", "!AIVDO", "!ABVDM", "!BSVDM"))
    has_fixes = any(f"{talker}{kind}," in head for talker in ("$GP", "$GN", "$GL", "$GA", "$II", "$IN")
                    for kind in ("RMC", "GGA"))
    return has_ais and not has_fixes


def _track(path: Path, kind: str, utc: list[datetime], lat: list[float], lon: list[float],
           heading: np.ndarray, notes: list[str], **sigmas: np.ndarray | None) -> Track:
    """A vessel track; ``sigmas``: its accuracy figures (Track's names), None where none is
    stated for any sample."""
    start = min(utc)
    t_s = np.array([(u - start).total_seconds() for u in utc])
    return Track(source=path, kind=kind, t_s=t_s, lat_deg=np.array(lat), lon_deg=np.array(lon),
                 heading_deg=heading, utc_start=start, clock="seconds since the first fix (UTC)",
                 notes=notes, **{name: none_if_missing(values) for name, values in sigmas.items()})


#: how long (s) an NMEA fix's speed and course carry the vessel where the fixes stop (a
#: receiver that loses its fix under a crane or a bridge for a few seconds)
NMEA_DEAD_RECKON_S = POSITION_GAP_DEAD_RECKON_S


def read_vessel_nmea(path: str | Path, max_heading_gap_s: float = 2.0) -> Track:
    path = Path(path)
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    decoder = NmeaDecoder()
    fixes: list[tuple[datetime, float, float]] = []       # in arrival order
    headings: list[tuple[int, float, str]] = []           # (index of the last fix, degrees, source)
    magnetic: list[tuple[int, float, str]] = []           # HDM / HDG without variation
    qualities: dict[int, tuple[int, float]] = {}          # fix index: GGA quality, HDOP
    errors: list[tuple[int, time, float]] = []            # GST: last fix index, time, sigma m
    motion: dict[int, tuple[float, float]] = {}           # fix index: RMC speed, course
    turns: list[tuple[int, float]] = []                   # ROT: last fix index, deg/s
    for number, line in enumerate(lines, start=1):
        for event in decoder.feed(line, number):
            if isinstance(event, Fix):
                if event.new:
                    fixes.append((event.utc, event.lat_deg, event.lon_deg))
                if math.isfinite(event.sog_mps):             # the RMC of the epoch's fix
                    motion[len(fixes) - 1] = (event.sog_mps, event.cog_deg)
                if event.quality is not None:
                    qualities[len(fixes) - 1] = (event.quality, event.hdop)
            elif isinstance(event, Heading):
                (headings if event.true else magnetic).append((len(fixes) - 1, event.deg, event.source))
            elif isinstance(event, RateOfTurn):
                turns.append((len(fixes) - 1, event.deg_s))
            elif isinstance(event, Gst):
                errors.append((len(fixes) - 1, event.clock, event.sigma_m))
    if not fixes:
        raise InputError(path, None, "no NMEA position fix with a date (RMC, or GGA after an "
                         "RMC/ZDA) found")
    notes = []
    headings, magnetic = _one_source(headings, notes), _one_source(magnetic, notes)
    if magnetic and headings:
        notes.append(f"{len(magnetic)} magnetic heading(s) (HDM, or HDG without variation) "
                     "left out: the feed has true headings")
    elif magnetic:
        headings, note = _magnetic_to_true(magnetic, fixes)
        if not headings:
            raise InputError(path, None, note)
        notes.append(note)
    if not headings:
        raise InputError(path, None, "no heading (HDT, THS, HDG or HDM): the vessel's heading "
                         "cannot come from course over ground")
    notes += decoder.notes()
    position_sigma = _nmea_position_sigma(fixes, qualities, errors, decoder.unusable_gst, notes)
    t0 = min(f[0] for f in fixes)
    arrival_t = np.array([(f[0] - t0).total_seconds() for f in fixes])
    head_t = _heading_times(arrival_t, [epoch for epoch, _ in headings])
    order = np.argsort(head_t, kind="stable")
    head_t = head_t[order]
    head = np.rad2deg(np.unwrap(np.deg2rad(np.array([h for _, h in headings])[order])))
    fix_order = np.argsort(arrival_t, kind="stable")
    fix_t = arrival_t[fix_order]
    heading = _interp_within(fix_t, head_t, head, max_heading_gap_s) % 360.0
    timing = _heading_timing_note(arrival_t, head_t, head)
    if timing:
        notes.append(timing)
    if np.isnan(heading).any():
        notes.append(f"{int(np.isnan(heading).sum())} fix(es) with no heading within "
                     f"{max_heading_gap_s:g} s")
    ordered = [fixes[i] for i in fix_order]
    sog, cog = (np.array([motion.get(i, (np.nan, np.nan))[k] for i in fix_order])
                for k in (0, 1))
    rot = _rates_of_turn(turns, arrival_t, fix_t, max_heading_gap_s)
    if np.isfinite(rot).any():
        notes.append(f"{int(np.isfinite(rot).sum())} of {len(rot)} fix(es) have a rate of turn "
                     "(ROT) within reach: the vessel's own motion of each clearance takes it")
    track = _track(path, "nmea", [f[0] for f in ordered], [f[1] for f in ordered],
                   [f[2] for f in ordered], heading, notes,
                   position_sigma_m=position_sigma[fix_order], sog_mps=sog, cog_deg=cog,
                   rot_deg_s=rot)
    if track.sog_mps is not None:           # a fix dropped out: carried by the RMC before it
        track.dead_reckon_s = NMEA_DEAD_RECKON_S
        notes.append(f"{int(np.isfinite(sog).sum())} of {len(sog)} fix(es) give speed and "
                     f"course (RMC): across a gap in the fixes the vessel is carried by them up "
                     f"to {NMEA_DEAD_RECKON_S:g} s, its error bars widened for the time")
    return track


def _nmea_position_sigma(fixes: list[tuple[datetime, float, float]],
                         qualities: dict[int, tuple[int, float]],
                         errors: list[tuple[int, time, float]], unusable_gst: int,
                         notes: list[str]) -> np.ndarray:
    """Per-axis position sigma (m) of each fix, in arrival order (module docstring): its
    GST's where one matches its time, else its GGA quality class; NaN for neither. A GST
    belongs to the fix before it or the one after (receivers send it either side of the
    epoch's GGA), whichever has its time. Says what was used in ``notes``."""
    sigma = np.full(len(fixes), np.nan)
    unmatched = 0
    for last, clock, value in errors:
        clock = clock.replace(tzinfo=None)
        match = next((i for i in (last, last + 1)
                      if 0 <= i < len(fixes) and fixes[i][0].time() == clock), None)
        if match is None:
            unmatched += 1
        else:
            sigma[match] = value
    from_gst = np.isfinite(sigma)
    classed = [i for i in sorted(qualities) if not from_gst[i]]
    if classed:
        codes, hdops = zip(*(qualities[i] for i in classed), strict=True)
        sigma[classed] = per_axis_from_class_m(codes, hdops, GGA_QUALITY_CLASSES)
    by_class = [i for i in classed if np.isfinite(sigma[i])]
    parts = [f"GST latitude/longitude error RMS for {int(from_gst.sum())} of {len(fixes)} "
             "fixes"] if from_gst.any() else []
    if by_class:
        parts.append(f"the GGA quality class, widened by HDOP above 1, for {len(by_class)} ("
                     + count_codes([qualities[i][0] for i in by_class], GGA_NAMES) + ")")
    if parts:
        notes.append("position_sigma_m (per axis): " + "; ".join(parts))
    if unmatched:
        notes.append(f"{unmatched} GST sentence(s) left out: no fix at their time")
    if unusable_gst:
        notes.append(f"{unusable_gst} GST sentence(s) without a time or a usable latitude/"
                     "longitude error skipped")
    return sigma


def _one_source(headings: list[tuple[int, float, str]], notes: list[str]) -> list[tuple[int, float]]:
    """The headings ``(fix index, degrees)`` of one sensor in each fix interval: a feed with
    two heading sensors (a gyro and a magnetic compass, two GNSS compasses) would otherwise
    give the track whichever spoke last before each fix. Sensors are talkers
    (:func:`~harborsight.telemetry.nmea.heading_sensor`), ranked by their best sentence
    (:func:`~harborsight.telemetry.nmea.heading_rank`), then by how often they spoke; in each
    interval the best one that spoke there is used, so a sensor that falls silent hands over
    to the next. The others are noted with how far they differ from the first (the median,
    where both spoke in an interval)."""
    from harborsight.telemetry.nmea import heading_rank, heading_sensor

    by_sensor: dict[str, list[tuple[int, float, str]]] = {}
    for entry in headings:
        by_sensor.setdefault(heading_sensor(entry[2]), []).append(entry)
    if len(by_sensor) <= 1:
        return [(epoch, deg) for epoch, deg, _ in headings]
    rank = {sensor: min(heading_rank(source) for _, _, source in entries)
            for sensor, entries in by_sensor.items()}
    order = sorted(by_sensor, key=lambda sensor: (rank[sensor], -len(by_sensor[sensor])))
    spoke = {sensor: {epoch for epoch, _, _ in entries} for sensor, entries in by_sensor.items()}
    used_by = {epoch: next(sensor for sensor in order if epoch in spoke[sensor])
               for epoch, _, _ in headings}

    def name(sensor: str) -> str:
        kinds = sorted({source[-3:] for _, _, source in by_sensor[sensor]})
        return f"{sensor or 'no talker'} ({', '.join(kinds)})"

    first = {epoch: deg for epoch, deg, _ in reversed(by_sensor[order[0]])}
    for other in order[1:]:
        entries = by_sensor[other]
        used = sum(used_by[epoch] == other for epoch, _, _ in entries)
        differences = [(deg - first[epoch] + 180.0) % 360.0 - 180.0
                       for epoch, deg, _ in entries if epoch in first]
        left = len(entries) - used
        note = (f"{left} heading(s) from {name(other)} left out: the track uses {name(order[0])}"
                if left else f"headings from two sensors: the track uses {name(order[0])}")
        if used:
            note += f", and {name(other)}'s {used} where it was silent"
        if differences:
            note += (f" ({other or 'no talker'} differs from it by "
                     f"{float(np.median(differences)):+.1f} deg, the median)")
        notes.append(note)
    return [(epoch, deg) for epoch, deg, source in headings if used_by[epoch] == heading_sensor(source)]


def _magnetic_to_true(magnetic: list[tuple[int, float]], fixes: list[tuple[datetime, float, float]]
                      ) -> tuple[list[tuple[int, float]], str]:
    """Magnetic headings + the WMM declination at the fix each follows, and a note saying so."""
    true, declinations, failed = [], [], ""
    for epoch, value in magnetic:
        when, lat, lon = fixes[epoch]
        try:
            declination = magnetic_declination_deg(lat, lon, when)
        except ValueError as exc:
            failed = str(exc)
            continue
        declinations.append(declination)
        true.append((epoch, value + declination))
    if not true:
        return [], (f"{len(magnetic)} magnetic heading(s) (HDM, or HDG without variation) "
                    f"cannot be made true: {failed}")
    model = wmm_model_name(decimal_year(fixes[magnetic[0][0]][0]))
    spread = (f"{min(declinations):+.2f}" if max(declinations) - min(declinations) < 0.005
              else f"{min(declinations):+.2f} to {max(declinations):+.2f}")
    note = (f"{len(true)} magnetic heading(s) (HDM, or HDG without variation) made true with "
            f"the {model} declination, {spread} deg")
    if len(true) < len(magnetic):
        note += f"; {len(magnetic) - len(true)} left out: {failed}"
    return true, note


def _interp_within(at_t: np.ndarray, sample_t: np.ndarray, values: np.ndarray,
                   max_gap_s: float) -> np.ndarray:
    """``values`` (at the sorted times ``sample_t``) interpolated at ``at_t``; NaN where the
    nearest sample is more than ``max_gap_s`` away."""
    out = np.interp(at_t, sample_t, values)
    index = np.searchsorted(sample_t, at_t)
    last = len(sample_t) - 1
    nearest = np.minimum(np.abs(at_t - sample_t[np.clip(index - 1, 0, last)]),
                         np.abs(sample_t[np.clip(index, 0, last)] - at_t))
    out[nearest > max_gap_s] = np.nan
    return out


def _rates_of_turn(turns: list[tuple[int, float]], arrival_t: np.ndarray, fix_t: np.ndarray,
                   max_gap_s: float) -> np.ndarray:
    """The rate of turn (deg/s) at each fix (``fix_t``, in time order) from the ROT sentences,
    placed in time as headings are (:func:`_heading_times`) and interpolated; NaN where none
    lies within ``max_gap_s``."""
    if not turns:
        return np.full(len(fix_t), np.nan)
    turn_t = _heading_times(arrival_t, [epoch for epoch, _ in turns])
    order = np.argsort(turn_t, kind="stable")
    return _interp_within(fix_t, turn_t[order], np.array([rate for _, rate in turns])[order],
                          max_gap_s)


#: a feed's headings (as many as its fixes or fewer) whose timing can be a fix interval off
#: get a note when at its fastest turns that is at least this much heading (degrees)
HEADING_TIMING_NOTE_DEG = 0.5


def _heading_timing_note(fix_t: np.ndarray, head_t: np.ndarray, head_deg: np.ndarray) -> str | None:
    """A note when the headings' placement (:func:`_heading_times`) may cost heading: with one
    heading a fix interval or fewer, NMEA cannot say whether a heading sentence belongs to the
    fix before it or to the one after it (a burst may send HDT before or after RMC, and the
    file keeps no arrival times), so a heading placed at the fix before it may be up to an
    interval ``Δt`` early, ``ω·Δt`` of heading at a rate of turn ``ω`` (the fastest turns: the
    95th percentile of the headings' own rate). None when that is under
    :data:`HEADING_TIMING_NOTE_DEG` or when headings come faster than the fixes."""
    steps = np.diff(np.sort(fix_t))
    steps = steps[steps > 0]
    if len(head_t) < 2 or not len(steps) or len(head_t) > 1.5 * len(fix_t):
        return None
    interval_s = float(np.median(steps))
    dt = np.diff(head_t)
    rates = np.abs(np.diff(head_deg)[dt > 0] / dt[dt > 0])
    if not len(rates):
        return None
    fastest = float(np.percentile(rates, 95))
    if fastest * interval_s < HEADING_TIMING_NOTE_DEG:
        return None
    return (f"headings carry no time in NMEA: each is placed at the fix before it, so one sent "
            f"ahead of its own fix is up to a fix interval ({interval_s:.2g} s) early, at this "
            f"feed's fastest turns ({fastest:.1f} deg/s) {fastest * interval_s:.1f} deg of heading "
            "(a hull point 15 m from the antenna moves "
            f"{15 * math.radians(fastest * interval_s):.2f} m); --sigma vessel_heading_deg can "
            "widen the bars for it")


def _heading_times(fix_t: np.ndarray, epochs: list[int]) -> np.ndarray:
    """Heading sentences carry no time. The k-th of n headings after fix i is placed at
    ``t_i + k·(t_(i+1) − t_i)/n``: evenly over the interval to the next fix (the median
    interval after the last), as a receiver sending headings at a steady rate would."""
    epochs_arr = np.asarray(epochs)
    steps = np.diff(fix_t)
    typical = float(np.median(steps[steps > 0])) if (steps > 0).any() else 1.0
    times = np.empty(len(epochs_arr))
    for epoch in np.unique(epochs_arr):
        members = np.flatnonzero(epochs_arr == epoch)
        step = fix_t[epoch + 1] - fix_t[epoch] if epoch + 1 < len(fix_t) else typical
        step = step if step > 0 else typical
        times[members] = fix_t[epoch] + np.arange(len(members)) * step / len(members)
    return times


def read_vessel_csv(path: str | Path) -> Track:
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as stream:   # Excel's "CSV UTF-8"
            rows = list(csv.DictReader(stream))
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    except (csv.Error, UnicodeDecodeError) as exc:
        raise InputError(path, None, f"not a readable CSV: {exc}") from None
    if not rows:
        raise InputError(path, None, "no rows")
    heading_column = "heading_deg" if "heading_deg" in rows[0] else "heading_mag_deg"
    missing = [c for c in ("time", "lat", "lon", heading_column) if c not in rows[0]]
    if missing:
        raise InputError(path, missing[0].replace("heading_mag_deg", "heading_deg"),
                         "missing column (need time, lat, lon and heading_deg, or "
                         "heading_mag_deg for a magnetic heading)")
    utc, lat, lon, heading, bad, declinations = [], [], [], [], [], []
    sigma_columns = [c for c in ("position_sigma_m", "heading_sigma_deg") if c in rows[0]]
    sigmas: dict[str, list[float]] = {c: [] for c in sigma_columns}
    for line, row in enumerate(rows, start=2):
        try:
            when = _csv_time(row["time"])
            row_lat = _csv_number(row["lat"], -90, 90, "lat")
            row_lon = _csv_number(row["lon"], -180, 180, "lon")
            value = _csv_number(row[heading_column], -360, 360, heading_column)
            row_sigmas = {c: _csv_sigma(row[c], c) for c in sigma_columns}
            if heading_column == "heading_mag_deg":
                declinations.append(magnetic_declination_deg(row_lat, row_lon, when))
                value += declinations[-1]
        except ValueError as exc:
            bad.append(f"line {line}: {exc}")
            continue
        for column, sigma in row_sigmas.items():
            sigmas[column].append(sigma)
        utc.append(when)
        lat.append(row_lat)
        lon.append(row_lon)
        heading.append(value)
    if not heading:
        raise InputError(path, None, "no readable row: " + "; ".join(bad[:3]))
    notes = [f"{len(bad)} row(s) skipped: " + "; ".join(bad[:5]) + ("; ..." if len(bad) > 5 else "")
             ] if bad else []
    if declinations:
        notes.append(f"heading_mag_deg made true with the {wmm_model_name(decimal_year(utc[0]))}"
                     f" declination, {min(declinations):+.2f} to {max(declinations):+.2f} deg")
    return _track(path, "csv", utc, lat, lon, np.array(heading), notes,
                  **{column: np.array(values) for column, values in sigmas.items()})


def _csv_time(text: str | None) -> datetime:
    try:
        when = datetime.fromisoformat((text or "").strip())
    except ValueError:
        raise ValueError(f"time: expected ISO 8601 with a zone, got {text!r}") from None
    if when.tzinfo is None:
        raise ValueError(f"time: {text!r} has no time zone")
    return when.astimezone(UTC)


def _csv_sigma(text: str | None, column: str) -> float:
    """An optional sigma cell: NaN where empty, else a number above 0 and at most
    :data:`MAX_SIGMA_M` (ValueError otherwise)."""
    if text is None or not text.strip():
        return math.nan
    value = _csv_number(text, 0.0, MAX_SIGMA_M, column)
    if value <= 0:
        raise ValueError(f"{column}: {value} is not above 0")
    return value


def _csv_number(text: str | None, low: float, high: float, column: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{column}: expected a number, got {text!r}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{column}: {value} is outside [{low}, {high}]")
    return value
