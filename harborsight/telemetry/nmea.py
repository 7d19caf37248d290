"""NMEA 0183 sentence by sentence: what a vessel's feed says, one line at a time.

:class:`NmeaDecoder` is shared by the file reader (:func:`harborsight.telemetry.vessel_track.
read_vessel_nmea`) and the live feed (:mod:`harborsight.live.nmea_in`, UDP, TCP or serial).
It keeps the little state a feed needs (the date from the last ``RMC``/``ZDA``, the last fix's
time) and turns each line into events:

* :class:`Fix`: a measured position at a UTC time. ``RMC`` and ``GGA`` of one epoch give one
  fix (``new`` is False for the second); a ``GGA`` also carries its quality and HDOP. A fix
  whose time of day is over 12 h before the previous one's is in the next day (a ``GGA`` after
  midnight, before the next ``RMC``/``ZDA`` brings the date). A ``GGA`` before any date is
  skipped in a file; live (``now_utc``), it is dated by the machine's clock, the day that
  puts it nearest to now (a GNSS compass may send ``GGA``, ``HDT`` and ``VTG`` only). Fixes
  come from one position sensor: the first talker family to give one (the satellite
  talkers ``GP``, ``GN``, ``GL``, ``GA``, ``GB``, ``BD``, ``GQ``, ``GI`` are one
  receiver's; ``AI``, an AIS transponder's own
  receiver, ``II``, ``IN`` and the rest each their own). Another sensor's fixes are counted
  in ``skipped`` and left out: two receivers metres apart mixed make the vessel jump between
  them. It takes over when the first has given no fix for :data:`POSITION_SENSOR_HOLD_S`.
* :class:`Heading`: ``HDT``/``THS`` (true), ``HDG`` with variation (made true with its deviation
  and variation), ``HDM`` and ``HDG`` without variation (``true`` False: magnetic, deviation
  applied). Headings before the first fix are counted, not emitted.
* :class:`Gst`: the latitude/longitude error RMS (per axis, m) of the fix at ``clock``.
* :class:`RateOfTurn`: ``ROT`` with status A (degrees per minute in the sentence, deg/s in the
  event; status V counted as skipped); like headings, none before the first fix.

Sentences that are not measurements are counted in ``skipped`` (RMC status V or mode E/M/S/N,
GGA quality 0/6/7/8 or undefined, THS mode other than A); unreadable lines (bad checksum,
corrupt field) in ``bad_count`` with the first few line numbers in ``bad_lines``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, date, datetime, time, timedelta

from harborsight.telemetry.accuracy import GGA_QUALITY_CLASSES, per_axis_from_gst_m
from harborsight.telemetry.track import KNOT_MPS

RMC_MODES_NOT_MEASURED = {"E": "RMC mode E (estimated, dead reckoning)", "M": "RMC mode M (manual input)",
                          "S": "RMC mode S (simulator)", "N": "RMC mode N (data not valid)"}
GGA_QUALITIES_NOT_MEASURED = {0: "GGA quality 0 (no fix)",
                              6: "GGA quality 6 (dead reckoning, not a measured position)",
                              7: "GGA quality 7 (manual input, not a measured position)",
                              8: "GGA quality 8 (simulator, not a measured position)"}
THS_MODES_NOT_MEASURED = {"E": "THS mode E (estimated heading)", "M": "THS mode M (manual input)",
                          "S": "THS mode S (simulator)", "V": "THS mode V (heading not valid)"}
#: how many unreadable lines are named one by one
BAD_LINES_KEPT = 5
#: talkers of one satellite receiver (GPS, GNSS, GLONASS, Galileo, BeiDou, QZSS, NavIC)
SATELLITE_TALKERS = frozenset({"GP", "GN", "GL", "GA", "GB", "BD", "GQ", "GI"})
#: a second position sensor takes over after the first gave no fix for this long (s, UTC)
POSITION_SENSOR_HOLD_S = 5.0


def position_sensor(talker: str) -> str:
    """The position sensor a fix's talker stands for: ``GNSS`` for a satellite receiver's
    talkers, else the talker itself."""
    return "GNSS" if talker in SATELLITE_TALKERS else talker


@dataclass(frozen=True)
class Fix:
    utc: datetime
    lat_deg: float
    lon_deg: float
    new: bool                        # False: the same epoch as the previous fix (RMC + GGA)
    quality: int | None = None       # GGA fix quality
    hdop: float = math.nan
    #: speed (m/s) and course (deg true) over ground: RMC's, NaN for a GGA
    sog_mps: float = math.nan
    cog_deg: float = math.nan


@dataclass(frozen=True)
class Heading:
    deg: float
    true: bool                       # False: magnetic (deviation applied), needs the declination
    #: talker and sentence ("HEHDT", "HCHDG"): a feed may carry two heading sensors (a gyro
    #: and a magnetic compass, two GNSS compasses), each read on its own (:func:`heading_rank`)
    source: str = ""


def rmc_motion(sentence) -> tuple[float, float]:
    """An RMC's speed (m/s) and course (deg true) over ground; NaN for an empty field (a
    receiver at rest leaves the course empty)."""
    speed, course = number(sentence.spd_over_grnd), number(sentence.true_course)
    sog = speed * KNOT_MPS if math.isfinite(speed) and 0 <= speed < 1000 else math.nan
    cog = course % 360.0 if math.isfinite(course) and -360 <= course <= 720 else math.nan
    return sog, cog


def heading_rank(source: str) -> int:
    """Which heading sentence a vessel track prefers when a feed has several sensors (lowest
    first): a true heading sentence (HDT, THS: a gyro or a GNSS compass) before an HDG made
    true with its own variation (a magnetic compass), before the rest."""
    kind = source[-3:]
    return 0 if kind in ("HDT", "THS") else 1 if kind == "HDG" else 2


def heading_sensor(source: str) -> str:
    """The sensor a heading sentence comes from: its talker (``HE`` of ``HEHDT``); one
    compass sends its HDG and its HDM under one talker."""
    return source[:-3]


@dataclass(frozen=True)
class Gst:
    clock: time                      # the UTC time of the fix it belongs to
    sigma_m: float                   # per horizontal axis


@dataclass(frozen=True)
class RateOfTurn:
    """A ``ROT`` sentence's rate of turn (a rate gyro's, or a gyrocompass's), deg/s; negative
    when the bow turns to port."""

    deg_s: float


Event = Fix | Heading | Gst | RateOfTurn

#: the largest rate of turn (deg/min) a ROT sentence is read with: beyond, a corrupt field
MAX_ROT_DEG_MIN = 10_000.0


@functools.cache
def teach_pynmea2_ths() -> None:
    """Register THS (true heading and status, NMEA 0183 v3 on), which pynmea2 does not define:
    heading in degrees true, then a mode: A autonomous, E estimated, M manual, S simulator,
    V not valid. pynmea2 registers every TalkerSentence subclass by its name."""
    import pynmea2

    class THS(pynmea2.TalkerSentence):
        fields = (("Heading", "heading", float), ("Mode indicator", "mode"))


def number(value) -> float:
    """An NMEA number field as a float; NaN where it is empty or not a number."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def angle(value) -> float:
    """An NMEA angle field in degrees; ValueError (the sentence is skipped as unreadable) for
    one that is not finite or beyond a turn (a corrupt field such as 1e308)."""
    degrees = float(value)
    if not (math.isfinite(degrees) and abs(degrees) <= 360.0):
        raise ValueError(f"angle {value!r} is not within one turn")
    return degrees


def utc_of(day: date, clock: time) -> datetime:
    return datetime.combine(day, clock.replace(tzinfo=None)).replace(tzinfo=UTC)


@dataclass
class NmeaDecoder:
    """Lines in, events out (module docstring)."""

    day: date | None = None
    last_fix_utc: datetime | None = None
    #: live: this machine's UTC clock, which dates a GGA before any RMC or ZDA gave the date
    #: (a GNSS compass sending GGA, HDT and VTG only): the day that puts its time of day
    #: nearest to now. None (files): such fixes are counted in ``undated`` and skipped
    now_utc: Callable[[], datetime] | None = None
    #: GGA fixes dated by this machine's clock
    machine_dated: int = 0
    bad_count: int = 0
    bad_lines: list[int] = field(default_factory=list)
    undated: int = 0                 # GGA fixes before the first date
    unusable_gst: int = 0
    #: the position sensor fixes are taken from, and when it gave its last one
    position_sensor: str | None = None
    position_sensor_last: datetime | None = None
    skipped: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ["RMC status V (no fix)", *RMC_MODES_NOT_MEASURED.values(),
         *GGA_QUALITIES_NOT_MEASURED.values(), *THS_MODES_NOT_MEASURED.values(),
         "GGA quality code the standard does not define", "headings before the first fix",
         "ROT status V or no rate (not valid)", "rates of turn before the first fix"], 0))

    def __post_init__(self) -> None:
        teach_pynmea2_ths()

    def _bad(self, number_: int | None) -> None:
        self.bad_count += 1
        if number_ is not None and len(self.bad_lines) < BAD_LINES_KEPT:
            self.bad_lines.append(number_)

    def feed(self, line: str, line_number: int | None = None) -> list[Event]:
        """The events of one line (text before a ``$`` is ignored; a line without one is not
        a sentence and yields nothing)."""
        import pynmea2

        line = line.strip()
        start = line.find("$")
        if start < 0:
            return []
        try:
            sentence = pynmea2.parse(line[start:], check=True)
        except pynmea2.ParseError:
            self._bad(line_number)
            return []
        try:
            return self._events(sentence)
        except (ValueError, TypeError, AttributeError):
            self._bad(line_number)
            return []

    def _day_nearest_now(self, clock: time) -> date:
        """The UTC day, yesterday, today or tomorrow by this machine's clock, that puts the
        time of day ``clock`` nearest to now (a fix stamped 23:59:59 read just past midnight
        is yesterday's)."""
        now = self.now_utc()
        days = [now.date() + timedelta(days=k) for k in (-1, 0, 1)]
        return min(days, key=lambda day: abs((utc_of(day, clock) - now).total_seconds()))

    def _fix(self, clock: time, lat: float, lon: float, quality: int | None = None,
             hdop: float = math.nan, talker: str = "", day: date | None = None,
             motion: tuple[float, float] = (math.nan, math.nan)) -> list[Fix]:
        if not (math.isfinite(lat) and math.isfinite(lon) and abs(lat) <= 90 and abs(lon) <= 180):
            raise ValueError(f"position {lat}, {lon} is off the globe")   # a bad field: skipped
        when = utc_of(day or self.day, clock)
        last = self.last_fix_utc
        if last is not None and when < last - timedelta(hours=12):
            when += timedelta(days=1)          # past midnight, before the next date arrives
        if not self._from_position_sensor(position_sensor(talker), when):
            return []
        new = last is None or last != when     # RMC and GGA of one fix count once
        self.last_fix_utc = when
        return [Fix(when, lat, lon, new, quality, hdop, *motion)]

    def _from_position_sensor(self, sensor: str, when: datetime) -> bool:
        """Whether a fix of ``sensor`` at ``when`` is taken (module docstring); one that is
        not is counted in ``skipped``."""
        chosen, last = self.position_sensor, self.position_sensor_last
        # another sensor takes over only with a fix timed more than the hold after the
        # chosen one's last (one whose clock lags, timed before it, never does)
        if chosen is not None and sensor != chosen and last is not None and (
                (when - last).total_seconds() <= POSITION_SENSOR_HOLD_S):
            key = f"fixes from a second position sensor ({sensor}) while {chosen} gives them"
            self.skipped[key] = self.skipped.get(key, 0) + 1
            return False
        self.position_sensor, self.position_sensor_last = sensor, when
        return True

    def _events(self, sentence) -> list[Event]:
        kind = sentence.sentence_type
        skipped = self.skipped
        if kind == "ZDA" and sentence.datestamp is not None:
            self.day = sentence.datestamp
        elif kind == "RMC":
            if sentence.datestamp is not None:
                self.day = sentence.datestamp
            mode = (getattr(sentence, "mode_indicator", None) or "").strip()[:1]
            if sentence.status != "A":
                skipped["RMC status V (no fix)"] += 1
            elif mode in RMC_MODES_NOT_MEASURED:
                skipped[RMC_MODES_NOT_MEASURED[mode]] += 1
            elif sentence.timestamp is not None and self.day is not None:
                return self._fix(sentence.timestamp, sentence.latitude, sentence.longitude,
                                 talker=sentence.talker, motion=rmc_motion(sentence))
        elif kind == "GGA":
            quality = int(sentence.gps_qual or 0)
            if quality in GGA_QUALITIES_NOT_MEASURED:
                skipped[GGA_QUALITIES_NOT_MEASURED[quality]] += 1
            elif quality not in GGA_QUALITY_CLASSES:
                skipped["GGA quality code the standard does not define"] += 1
            elif sentence.timestamp is not None:
                if self.day is None and self.now_utc is None:
                    self.undated += 1
                    return []
                day = self.day if self.day is not None else self._day_nearest_now(sentence.timestamp)
                if self.day is None:
                    self.machine_dated += 1
                return self._fix(sentence.timestamp, sentence.latitude, sentence.longitude,
                                 quality, number(sentence.horizontal_dil), sentence.talker, day)
        elif kind == "GST":
            sigma_m = per_axis_from_gst_m(number(sentence.std_dev_latitude),
                                          number(sentence.std_dev_longitude))
            if isinstance(sentence.timestamp, time) and math.isfinite(sigma_m):
                return [Gst(sentence.timestamp, sigma_m)]
            self.unusable_gst += 1
        elif kind == "ROT":
            rate = number(getattr(sentence, "rate_of_turn", None))
            if (sentence.status or "").strip()[:1] != "A" or not (
                    math.isfinite(rate) and abs(rate) <= MAX_ROT_DEG_MIN):
                skipped["ROT status V or no rate (not valid)"] += 1
            elif self.last_fix_utc is None:
                skipped["rates of turn before the first fix"] += 1
            else:
                return [RateOfTurn(rate / 60.0)]
        elif kind == "THS" and (sentence.mode or "").strip()[:1] != "A":
            skipped[THS_MODES_NOT_MEASURED.get((sentence.mode or "").strip()[:1],
                                               "THS mode V (heading not valid)")] += 1
        elif kind in ("HDT", "THS", "HDG", "HDM") and sentence.heading is not None:
            if self.last_fix_utc is None:
                skipped["headings before the first fix"] += 1
                return []
            source = f"{getattr(sentence, 'talker', '') or ''}{kind}"
            if kind in ("HDT", "THS"):
                return [Heading(angle(sentence.heading), True, source)]
            elif kind == "HDM":
                return [Heading(angle(sentence.heading), False, source)]
            else:
                deviation = angle(sentence.deviation or 0) * (-1 if sentence.dev_dir == "W" else 1)
                if sentence.variation is None:
                    return [Heading(angle(sentence.heading) + deviation, False, source)]
                variation = angle(sentence.variation) * (-1 if sentence.var_dir == "W" else 1)
                return [Heading(angle(sentence.heading) + deviation + variation, True, source)]
        return []

    def notes(self) -> list[str]:
        """What was left out, in words (for a track's notes or a live warning)."""
        out = []
        if self.bad_count:
            shown = ", ".join(map(str, self.bad_lines)) + (
                ", ..." if self.bad_count > len(self.bad_lines) else "")
            out.append(f"{self.bad_count} unreadable sentence(s) skipped (bad checksum or field"
                       + (f"; line{'s' if self.bad_count > 1 else ''} {shown})" if shown else ")"))
        if self.undated:
            out.append(f"{self.undated} GGA fix(es) before the first date (RMC/ZDA) skipped")
        if self.machine_dated:
            out.append(f"{self.machine_dated} GGA fix(es) before the first date (RMC/ZDA) dated by "
                       "this machine's UTC clock")
        out += [f"{count} sentence(s) skipped: {what}" for what, count in self.skipped.items() if count]
        return out
