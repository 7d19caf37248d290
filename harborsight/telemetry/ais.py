"""AIS (AIVDM/AIVDO, decoded with pyais): the vessel's track from its own transponder, and its
hull's dimensions.

Sentences are read line by line; a line that cannot be read (bad checksum, a corrupt payload,
a message type pyais does not know) is counted and skipped, and multi-part messages are
assembled from their fragments (by sequence id and channel; a fragment whose partners never
come is counted). Messages of other vessels are counted and left out: ``mmsi`` picks the
vessel, and without it the file must hold one vessel's own reports (``!AIVDO``) or one MMSI.

Time. A position report holds only the second of the minute of its fix (``second``, 60 = not
available). Its UTC time comes from the receiver: an NMEA 4.10 tag block's ``c:`` (Unix
seconds, or milliseconds) before the sentence, or an ISO 8601 time at the start of the line
(as many loggers write), moved to the nearest time whose second is the report's (the
transponder's delay removed, up to ±30 s). A file with neither has no usable time and is
refused.

Position reports: types 1, 2, 3 (class A), 18 and 19 (class B); a longitude of 181 or latitude
of 91 means none, and a time stamp of 61-63 a position no working fix gave (manual input,
dead reckoning, the position system inoperative: a transponder that lost its GPS repeats its
last position); both are counted and skipped. Heading: the true heading (511 = not
available); without one the report is refused, or, with ``allow_cog_heading``, takes the
course over ground (3600 = none) with a note, since a vessel berthing moves sideways and its
course is not its heading.

Motion: each report's speed (0.1 kn; 102.3 = none) and course over ground (360 = none) go
with its position, and the track carries the vessel between reports by them for up to
``AIS_FRAME_REACH_S`` (:mod:`harborsight.telemetry.track`, "Dead reckoning"): a class A
transponder under way reports every 10 s, and without it every frame more than a second
from a report had no vessel pose. A frame carried longer than ``AIS_DEAD_RECKON_S`` is
measured only where the frames before it placed the vessel in the image
(:mod:`harborsight.flight.pose_carry`): a class B transponder reports every 30 s under way
and every 3 min under 2 kn.

Dimensions (types 5 and 24 part B, and 19): A to the bow, B to the stern, C to port, D to
starboard, in metres from the position reference point: exactly the vessel frame's origin
(design.md). 0 means not available; 511 (A, B) and 63 (C, D) mean that many metres or more.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.geometry.sensor_sigmas import MAX_DEAD_RECKONED_S
from harborsight.telemetry.track import KNOT_MPS, Track, carried_by_motion

POSITION_TYPES = frozenset({1, 2, 3, 18, 19})
DIMENSION_TYPES = frozenset({5, 19, 24})
_LEADING_TIME = re.compile(r"^\s*(\d{4}-\d\d-\d\d[T ]\d\d:\d\d:\d\d(?:\.\d+)?(?:Z|[+-]\d\d:?\d\d)?)")


@dataclass
class AisReport:
    mmsi: int
    msg_type: int
    received: datetime | None
    own: bool                                   # !AIVDO: the receiving vessel's own report
    fields: dict


@dataclass
class AisFile:
    """The decoded messages of a file, and what was left out."""

    path: Path
    reports: list[AisReport] = field(default_factory=list)
    unreadable: int = 0
    unsupported: int = 0
    orphan_fragments: int = 0
    #: lines whose leading receiver time has no zone, taken as UTC
    zoneless_times: int = 0

    def notes(self) -> list[str]:
        out = []
        if self.zoneless_times:
            out.append(f"{self.zoneless_times} receiver time(s) at the start of a line carry no "
                       "zone and are taken as UTC: a logger writing local time puts the vessel "
                       "hours off (the reports' second of the minute cannot tell); write the "
                       "zone ('Z', '+02:00') to be sure")
        if self.unreadable:
            out.append(f"{self.unreadable} unreadable AIS line(s) skipped (bad checksum or payload)")
        if self.unsupported:
            out.append(f"{self.unsupported} AIS message(s) of types pyais does not decode skipped")
        if self.orphan_fragments:
            out.append(f"{self.orphan_fragments} fragment(s) of multi-part messages whose other "
                       "parts never came skipped")
        return out


def _tag_block_time(block: str) -> datetime | None:
    """``c:`` of an NMEA 4.10 tag block (``s:rx1,c:1777636800*hh``), checksum checked."""
    body, _, checksum = block.partition("*")
    expected = 0
    for char in body:
        expected ^= ord(char)
    if checksum and checksum[:2].upper() != f"{expected:02X}":
        return None
    match = re.search(r"(?:^|,)c:(\d{1,14}(?:\.\d+)?)(?:,|$)", body)
    if not match:
        return None
    value = float(match[1])
    if value > 1e11:               # milliseconds
        value /= 1000.0
    return datetime.fromtimestamp(value, UTC) if 0 < value < 253402300800 else None


def _received(line: str, start: int) -> tuple[datetime | None, bool]:
    """The receiver's time of the sentence starting at ``start`` (module docstring), and
    whether it was a leading time without a zone, taken as UTC."""
    block = re.search(r"\\([^\\]*)\\\s*$", line[:start])
    if block:
        when = _tag_block_time(block[1])
        if when is not None:
            return when, False
    match = _LEADING_TIME.match(line)
    if match:
        try:
            when = datetime.fromisoformat(match[1].replace("Z", "+00:00").replace(" ", "T"))
        except ValueError:
            return None, False
        return (when, False) if when.tzinfo else (when.replace(tzinfo=UTC), True)
    return None, False


def receiver_time(line: str) -> datetime | None:
    """When the receiver logged ``line``'s AIS sentence (its tag block's ``c:``, or an ISO
    8601 time before it), or None."""
    start = sentence_start(line)
    return _received(line, start)[0] if start >= 0 else None


def restamped(sentence: str, second: int) -> str:
    """A single-part position report (types 1, 2, 3, 18, 19) re-encoded with ``second`` as
    its time stamp (0-59), or ``sentence`` unchanged (other messages, parts of multi-part
    ones, a time stamp saying none or no working fix: 60-63). A recording replayed now must
    carry the seconds of now: a receiver dates each report by its own clock's minute and the
    report's second (:func:`fix_time`)."""
    from pyais.encode import encode_dict
    from pyais.messages import NMEAMessage

    try:
        message = NMEAMessage.from_string(sentence.strip())
        if not message.is_valid or message.frag_cnt != 1:
            return sentence
        fields = message.decode().asdict()
    except Exception:                    # pyais's errors are many types
        return sentence
    if fields.get("msg_type") not in POSITION_TYPES or not 0 <= (fields.get("second") or 0) <= 59:
        return sentence
    fields["second"] = second
    return encode_dict(fields, talker_id=message.talker, sentence_type=message.type,
                       radio_channel=message.channel or "A")[0]


def sentence_start(line: str) -> int:
    """Where a line's AIS sentence (``!AIVDM``/``!AIVDO``, base station ``!ABVD``/``!BSVD``)
    starts; −1 for a line without one."""
    return max(line.find("!AIVD"), line.find("!ABVD"), line.find("!BSVD"))


def report_identity(fields: dict) -> tuple[int, int] | None:
    """A decoded message's MMSI and type, or None where its payload was cut inside them
    (pyais then decodes them as None)."""
    mmsi, kind = fields.get("mmsi"), fields.get("msg_type")
    return (mmsi, kind) if isinstance(mmsi, int) and isinstance(kind, int) else None


def report_position(fields: dict) -> tuple[float, float] | None:
    """A report's latitude and longitude, or None where it has none (91 / 181)."""
    lat, lon = fields.get("lat"), fields.get("lon")
    if lat is None or lon is None or abs(lat) > 90 or abs(lon) > 180:
        return None
    return float(lat), float(lon)


#: the time stamp (``second``) values of a position that no working position fix gave
UNMEASURED_SECONDS = {61: "manual input", 62: "dead reckoning", 63: "position system inoperative"}


def unmeasured_position(fields: dict) -> str | None:
    """Why a report's position was not measured, from its time stamp (61 manual input, 62
    dead reckoning, 63 the position system inoperative: a transponder that lost its GPS
    repeats its last position), or None for a measured one (0-59, or 60 for no time)."""
    second = fields.get("second")
    return UNMEASURED_SECONDS.get(second) if isinstance(second, int) else None


#: how long (s) a report's speed and course carry the vessel for a measurement where no
#: later report is in reach: a class A transponder reports every 10 s under way at up to
#: 14 kn (2-6 s faster or turning); one report missed leaves a gap. The live aid counts the
#: vessel's source stale after it
AIS_DEAD_RECKON_S = MAX_DEAD_RECKONED_S
#: how far (s) from a report a track read from a file still gives frames a vessel pose
#: (dead-reckoned, ``vessel.dead_reckoned_s`` saying for how long): a class B transponder
#: reports every 3 min under 2 kn. Beyond :data:`AIS_DEAD_RECKON_S` such a frame is measured
#: only where the frames before it placed the vessel in the image
#: (:mod:`harborsight.flight.pose_carry`); the frame's drone pose is kept for that
AIS_FRAME_REACH_S = 200.0


def report_motion(fields: dict) -> tuple[float, float]:
    """A report's speed over ground (m/s) and course over ground (deg true); NaN for what it
    does not give (speed 102.3 kn, course 360)."""
    speed, course = fields.get("speed"), fields.get("course")
    sog = (float(speed) * KNOT_MPS if isinstance(speed, (int, float)) and 0 <= speed < 102.25
           else math.nan)
    cog = float(course) if isinstance(course, (int, float)) and 0 <= course < 360 else math.nan
    return sog, cog


def report_turn(fields: dict) -> float:
    """A report's rate of turn (deg/s, clockwise) as pyais decodes it (deg/min); NaN where
    it gives none: -128 (not available), ±127 (turning faster than 5° in 30 s, no rate)."""
    turn = fields.get("turn")
    if not isinstance(turn, (int, float)) or abs(turn) >= 127:
        return math.nan
    return float(turn) / 60.0


def report_heading(fields: dict, allow_cog_heading: bool) -> tuple[float | None, bool]:
    """A report's true heading (module docstring), or with ``allow_cog_heading`` its course
    over ground where the heading is 511; and whether the course was used."""
    heading = fields.get("heading")
    if heading is not None and heading != 511 and 0 <= heading < 360:
        return float(heading), False
    course = fields.get("course")
    if allow_cog_heading and course is not None and 0 <= course < 360:
        return float(course), True
    return None, False


def read_ais_file(path: str | Path) -> AisFile:
    """Every decodable message of an AIS log (module docstring)."""
    from pyais.messages import NMEAMessage

    path = Path(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    result = AisFile(path)
    pending: dict[tuple, list] = {}
    for line in text.splitlines():
        start = sentence_start(line)
        if start < 0:
            continue
        sentence = line[start:].strip()
        try:
            message = NMEAMessage.from_string(sentence)
            if not message.is_valid:
                raise ValueError("checksum")
        except Exception:          # pyais's parse errors are many types
            result.unreadable += 1
            continue
        received, zoneless = _received(line, start)
        result.zoneless_times += zoneless
        if message.frag_cnt > 1:
            key = (message.seq_id, message.channel, message.frag_cnt)
            parts = pending.setdefault(key, [])
            if message.frag_num == 1 and parts:
                result.orphan_fragments += len(parts)
                parts.clear()
            parts.append((message, received))
            if len(parts) < message.frag_cnt:
                continue
            del pending[key]
            try:
                message = NMEAMessage.assemble_from_iterable([p for p, _ in parts])
            except Exception:
                result.orphan_fragments += len(parts)
                continue
            received = next((r for _, r in parts if r is not None), None)
        try:
            decoded = message.decode()
        except Exception as exc:
            if type(exc).__name__ == "UnknownMessageException":
                result.unsupported += 1
            else:
                result.unreadable += 1
            continue
        values = decoded.asdict()
        identity = report_identity(values)
        if identity is None:
            result.unreadable += 1
            continue
        result.reports.append(AisReport(*identity, received, sentence[3:6] == "VDO", values))
    result.orphan_fragments += sum(len(parts) for parts in pending.values())
    return result


def pick_mmsi(ais: AisFile, mmsi: int | None) -> int:
    """The vessel's MMSI: the one asked for, else the file's own (VDO) reports', else its
    only vessel's; :class:`InputError` saying which to choose from otherwise."""
    seen = Counter(r.mmsi for r in ais.reports)
    if mmsi is not None:
        if mmsi not in seen:
            raise InputError(ais.path, "--mmsi", f"no message from MMSI {mmsi}; the file has "
                             + (", ".join(f"{m} ({n})" for m, n in seen.most_common(8)) or "none"))
        return mmsi
    own = {r.mmsi for r in ais.reports if r.own}
    if len(own) == 1:
        return own.pop()
    if len(seen) == 1:
        return next(iter(seen))
    if not seen:
        raise InputError(ais.path, None, "no decodable AIS message")
    raise InputError(ais.path, "--mmsi", f"{len(seen)} vessels in the file: give --mmsi, one of "
                     + ", ".join(f"{m} ({n} messages)" for m, n in seen.most_common(8)))


def fix_time(received: datetime, second: int | None) -> datetime:
    """The receiver's time moved to the nearest time whose second of the minute is the
    report's (module docstring)."""
    if second is None or not 0 <= second <= 59:
        return received
    base = received.replace(second=second, microsecond=0)
    candidates = []
    for minutes in (-1, 0, 1):
        try:
            candidates.append(base + timedelta(minutes=minutes))
        except OverflowError:           # a receiver time in the first or last minute of 1-9999
            continue
    return min(candidates, key=lambda c: abs((c - received).total_seconds()))


def read_ais_track(path: str | Path, mmsi: int | None = None, allow_cog_heading: bool = False
                   ) -> Track:
    """The position reports of one vessel as a vessel track (module docstring)."""
    ais = read_ais_file(path)
    chosen = pick_mmsi(ais, mmsi)
    others = sum(1 for r in ais.reports if r.mmsi != chosen)
    rows, untimed, no_position, no_heading, cog_used, unmeasured = [], 0, 0, 0, 0, 0
    for report in ais.reports:
        if report.mmsi != chosen or report.msg_type not in POSITION_TYPES:
            continue
        f = report.fields
        position = report_position(f)
        if position is None:
            no_position += 1
            continue
        if unmeasured_position(f) is not None:
            unmeasured += 1
            continue
        if report.received is None:
            untimed += 1
            continue
        heading, from_course = report_heading(f, allow_cog_heading)
        if heading is None:
            no_heading += 1
            continue
        cog_used += from_course
        second = f.get("second")
        rows.append((fix_time(report.received, second), *position, heading, *report_motion(f),
                     report_turn(f)))
    if untimed and not rows:
        raise InputError(ais.path, None, "AIS position reports carry only the second of the "
                         "minute: the file needs receiver times (NMEA 4.10 tag blocks with c:, or "
                         "an ISO 8601 time before each sentence)")
    if not rows:
        why = (f"{no_heading} report(s) without a true heading (511): a berthing vessel's "
               "course is not its heading; --allow-cog-heading uses it anyway" if no_heading
               else f"{unmeasured} position report(s) not from a working position fix (time "
               "stamp 61-63: manual input, dead reckoning, position system inoperative)"
               if unmeasured else "no position report (types 1, 2, 3, 18, 19) with a position")
        raise InputError(ais.path, None, f"MMSI {chosen}: {why}")
    rows.sort(key=lambda r: r[0])
    notes = ais.notes()
    if others:
        notes.append(f"{others} message(s) of other vessels left out (MMSI {chosen} kept)")
    for count, what in ((no_position, "without a position (lat 91 / lon 181)"),
                        (unmeasured, "not from a working position fix (time stamp 61-63: "
                                     "manual input, dead reckoning, position system inoperative)"),
                        (untimed, "without a receiver time"),
                        (no_heading, "without a true heading (511)")):
        if count:
            notes.append(f"{count} position report(s) {what} skipped")
    if cog_used:
        notes.append(f"WARNING: {cog_used} report(s) without a true heading use the course over "
                     "ground instead (--allow-cog-heading): wrong wherever the vessel moves "
                     "sideways")
    with_motion = int(carried_by_motion([r[4] for r in rows], [r[5] for r in rows]).sum())
    notes.append(f"{with_motion} of {len(rows)} report(s) give speed and course: the vessel is "
                 f"carried by them between reports, its error bars widened for the time "
                 f"(vessel.dead_reckoned_s); frames up to {AIS_FRAME_REACH_S:g} s from a report "
                 f"are written, those carried over {AIS_DEAD_RECKON_S:g} s measured only where "
                 "the frames before them placed the vessel in the image")
    start = rows[0][0]
    return Track(source=ais.path, kind="ais", t_s=np.array([(r[0] - start).total_seconds() for r in rows]),
                 lat_deg=np.array([r[1] for r in rows]), lon_deg=np.array([r[2] for r in rows]),
                 heading_deg=np.array([r[3] for r in rows]), sog_mps=np.array([r[4] for r in rows]),
                 cog_deg=np.array([r[5] for r in rows]), rot_deg_s=np.array([r[6] for r in rows]),
                 dead_reckon_s=AIS_DEAD_RECKON_S, frame_reach_s=AIS_FRAME_REACH_S,
                 utc_start=start,
                 clock="seconds since the first report (UTC, receiver time)", notes=notes)


@dataclass(frozen=True)
class AisDimensions:
    mmsi: int
    to_bow: int
    to_stern: int
    to_port: int
    to_starboard: int
    name: str | None = None
    at_least: tuple[str, ...] = ()            # fields at their largest code: that or more


def read_ais_dimensions(path: str | Path, mmsi: int | None = None) -> tuple[AisDimensions, list[str]]:
    """The vessel's newest complete dimensions (types 5, 19, 24 B) and the file's notes."""
    ais = read_ais_file(path)
    chosen = pick_mmsi(ais, mmsi)
    name, found = None, None
    for report in ais.reports:
        if report.mmsi != chosen:
            continue
        f = report.fields
        name = (f.get("shipname") or "").strip(" @") or name
        if report.msg_type in DIMENSION_TYPES and all(
                f.get(k) for k in ("to_bow", "to_stern", "to_port", "to_starboard")):
            found = f
    if found is None:
        raise InputError(ais.path, None, f"MMSI {chosen}: no static report (type 5, 19 or 24 "
                         "part B) with all four dimensions A, B, C, D (0 = not available)")
    at_least = tuple(k for k, top in (("to_bow", 511), ("to_stern", 511), ("to_port", 63),
                                      ("to_starboard", 63)) if found[k] >= top)
    return AisDimensions(chosen, int(found["to_bow"]), int(found["to_stern"]), int(found["to_port"]),
                         int(found["to_starboard"]), name, at_least), ais.notes()
