"""The vessel's own track: position and true heading over time, from the ship's NMEA 0183 feed
(read with pynmea2) or from a CSV.

NMEA: ``RMC`` gives UTC date, time and position; ``GGA`` time and position (its date comes from
the last ``RMC`` or ``ZDA``); ``HDT`` the true heading; ``HDG`` a magnetic heading that becomes
true with the deviation and variation it carries (skipped when it carries no variation).
Heading sentences have no time: those between two fixes are spread evenly over that interval
(:func:`_heading_times`). The heading at each position fix is then interpolated (on unwrapped
angles) from heading samples no more than ``max_heading_gap_s`` away. A fix whose time of day
is over 12 h before the previous one's is in the next day (a GGA after midnight, before the
next RMC/ZDA brings the date). Course over ground (``RMC``/``VTG``) is never used as heading: a
vessel berthing moves sideways.

CSV: a header line, then one row per sample, with columns ``time`` (ISO 8601 with a zone, e.g.
``2026-05-01T12:00:00.25Z``), ``lat``, ``lon`` (degrees) and ``heading_deg`` (true, clockwise
from north).
"""

from __future__ import annotations

import csv
import math
from datetime import UTC, date, datetime, time, timedelta
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.telemetry.track import Track


def read_vessel_track(path: str | Path, max_heading_gap_s: float = 2.0) -> Track:
    """NMEA 0183 (``.nmea``, ``.txt``, ``.log``) or CSV (``.csv``) by extension."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        return read_vessel_csv(path)
    return read_vessel_nmea(path, max_heading_gap_s)


def _track(path: Path, kind: str, utc: list[datetime], lat: list[float], lon: list[float],
           heading: np.ndarray, notes: list[str]) -> Track:
    start = min(utc)
    t_s = np.array([(u - start).total_seconds() for u in utc])
    return Track(source=path, kind=kind, t_s=t_s, lat_deg=np.array(lat), lon_deg=np.array(lon),
                 heading_deg=heading, utc_start=start, clock="seconds since the first fix (UTC)",
                 notes=notes)


def read_vessel_nmea(path: str | Path, max_heading_gap_s: float = 2.0) -> Track:
    import pynmea2

    path = Path(path)
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    day: date | None = None
    fixes: list[tuple[datetime, float, float]] = []       # in arrival order
    headings: list[tuple[int, float]] = []                # (index of the last fix, degrees)
    bad, undated, no_variation = [], 0, 0

    def add_fix(clock: time, lat: float, lon: float) -> None:
        when = _utc(day, clock)
        if fixes and when < fixes[-1][0] - timedelta(hours=12):
            when += timedelta(days=1)          # past midnight, before the next date arrives
        if not fixes or fixes[-1][0] != when:  # RMC and GGA of one fix count once
            fixes.append((when, lat, lon))

    for number, line in enumerate(lines, start=1):
        line = line.strip()
        start = line.find("$")
        if start < 0:
            continue
        try:
            sentence = pynmea2.parse(line[start:], check=True)
        except pynmea2.ParseError:
            bad.append(number)
            continue
        kind = sentence.sentence_type
        try:
            if kind == "ZDA" and sentence.datestamp is not None:
                day = sentence.datestamp
            elif kind == "RMC":
                if sentence.datestamp is not None:
                    day = sentence.datestamp
                if sentence.status == "A" and sentence.timestamp is not None and day is not None:
                    add_fix(sentence.timestamp, sentence.latitude, sentence.longitude)
            elif kind == "GGA":
                if int(sentence.gps_qual or 0) > 0 and sentence.timestamp is not None:
                    if day is None:
                        undated += 1
                        continue
                    add_fix(sentence.timestamp, sentence.latitude, sentence.longitude)
            elif kind == "HDT" and sentence.heading is not None and fixes:
                headings.append((len(fixes) - 1, float(sentence.heading)))
            elif kind == "HDG" and sentence.heading is not None and fixes:
                if sentence.variation is None:
                    no_variation += 1
                    continue
                deviation = float(sentence.deviation or 0) * (-1 if sentence.dev_dir == "W" else 1)
                variation = float(sentence.variation) * (-1 if sentence.var_dir == "W" else 1)
                headings.append((len(fixes) - 1, float(sentence.heading) + deviation + variation))
        except (ValueError, TypeError, AttributeError):
            bad.append(number)
    if not fixes:
        raise InputError(path, None, "no NMEA position fix with a date (RMC, or GGA after an "
                         "RMC/ZDA) found")
    if not headings:
        raise InputError(path, None, "no true heading (HDT, or HDG with variation): the "
                         "vessel's heading cannot come from course over ground")
    notes = []
    if bad:
        shown = ", ".join(map(str, bad[:5])) + (", ..." if len(bad) > 5 else "")
        notes.append(f"{len(bad)} unreadable sentence(s) skipped (bad checksum or field; "
                     f"line{'s' if len(bad) > 1 else ''} {shown})")
    if undated:
        notes.append(f"{undated} GGA fix(es) before the first date (RMC/ZDA) skipped")
    if no_variation:
        notes.append(f"{no_variation} HDG sentence(s) without magnetic variation skipped")
    t0 = min(f[0] for f in fixes)
    arrival_t = np.array([(f[0] - t0).total_seconds() for f in fixes])
    head_t = _heading_times(arrival_t, [epoch for epoch, _ in headings])
    order = np.argsort(head_t, kind="stable")
    head_t = head_t[order]
    head = np.rad2deg(np.unwrap(np.deg2rad(np.array([h for _, h in headings])[order])))
    fix_order = np.argsort(arrival_t, kind="stable")
    fix_t = arrival_t[fix_order]
    heading = np.interp(fix_t, head_t, head) % 360.0
    index = np.searchsorted(head_t, fix_t)
    nearest = np.minimum(np.abs(fix_t - head_t[np.clip(index - 1, 0, len(head_t) - 1)]),
                         np.abs(head_t[np.clip(index, 0, len(head_t) - 1)] - fix_t))
    heading[nearest > max_heading_gap_s] = np.nan
    if np.isnan(heading).any():
        notes.append(f"{int(np.isnan(heading).sum())} fix(es) with no heading within "
                     f"{max_heading_gap_s:g} s")
    ordered = [fixes[i] for i in fix_order]
    return _track(path, "nmea", [f[0] for f in ordered], [f[1] for f in ordered],
                  [f[2] for f in ordered], heading, notes)


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


def _utc(day: date, clock: time) -> datetime:
    return datetime.combine(day, clock.replace(tzinfo=None)).replace(tzinfo=UTC)


def read_vessel_csv(path: str | Path) -> Track:
    path = Path(path)
    try:
        with path.open(newline="") as stream:
            rows = list(csv.DictReader(stream))
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    except (csv.Error, UnicodeDecodeError) as exc:
        raise InputError(path, None, f"not a readable CSV: {exc}") from None
    if not rows:
        raise InputError(path, None, "no rows")
    missing = [c for c in ("time", "lat", "lon", "heading_deg") if c not in rows[0]]
    if missing:
        raise InputError(path, missing[0], "missing column (need time, lat, lon, heading_deg)")
    utc, lat, lon, heading, bad = [], [], [], [], []
    for line, row in enumerate(rows, start=2):
        try:
            utc.append(_csv_time(row["time"]))
            lat.append(_csv_number(row["lat"], -90, 90, "lat"))
            lon.append(_csv_number(row["lon"], -180, 180, "lon"))
            heading.append(_csv_number(row["heading_deg"], -360, 360, "heading_deg"))
        except ValueError as exc:
            del utc[len(heading):], lat[len(heading):], lon[len(heading):]
            bad.append(f"line {line}: {exc}")
    if not heading:
        raise InputError(path, None, "no readable row: " + "; ".join(bad[:3]))
    notes = [f"{len(bad)} row(s) skipped: " + "; ".join(bad[:5]) + ("; ..." if len(bad) > 5 else "")
             ] if bad else []
    return _track(path, "csv", utc, lat, lon, np.array(heading), notes)


def _csv_time(text: str | None) -> datetime:
    try:
        when = datetime.fromisoformat((text or "").strip())
    except ValueError:
        raise ValueError(f"time: expected ISO 8601 with a zone, got {text!r}") from None
    if when.tzinfo is None:
        raise ValueError(f"time: {text!r} has no time zone")
    return when.astimezone(UTC)


def _csv_number(text: str | None, low: float, high: float, column: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{column}: expected a number, got {text!r}") from None
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{column}: {value} is outside [{low}, {high}]")
    return value
