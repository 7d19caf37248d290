"""The vessel from its AIS transponder, live: ``--ais udp:PORT`` (or ``tcp:HOST:PORT``, a
serial device; the transports of :mod:`harborsight.live.nmea_in`) with ``--mmsi``.

Each position report (types 1, 2, 3, 18, 19) of the vessel goes into its live track at its
fix time: the arrival, moved back to the report's second of the minute (this machine's clock
gives the minute; a transponder sends within a few seconds of its fix). Reports without a
true heading (511) are skipped and warned about, or take the course over ground with
``--allow-cog-heading``. Other vessels' messages and unreadable lines are counted.
Frames are given the newest report's position carried by its speed and course for up to
``AIS_FRAME_REACH_S``; past ``AIS_DEAD_RECKON_S`` they are measured only where the frames
before them placed the vessel in the image (:mod:`harborsight.flight.pose_carry`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import UTC, datetime

from harborsight.live.telemetry import LiveTrack, worth_saying
from harborsight.telemetry.ais import (
    AIS_DEAD_RECKON_S,
    AIS_FRAME_REACH_S,
    POSITION_TYPES,
    fix_time,
    report_heading,
    report_identity,
    report_motion,
    report_position,
    report_turn,
    sentence_start,
    unmeasured_position,
)


class AisVessel:
    """Feeds AIVDM/AIVDO lines into the vessel's live track (module docstring)."""

    def __init__(self, track: LiveTrack, mmsi: int | None, *, allow_cog_heading: bool = False,
                 on_fix: Callable[[float], None] | None = None) -> None:
        self.track, self.mmsi, self.allow_cog_heading, self.on_fix = track, mmsi, allow_cog_heading, on_fix
        track.source_clock_is_utc()
        track.dead_reckon_s = AIS_DEAD_RECKON_S
        track.frame_reach_s = AIS_FRAME_REACH_S     # frames past 12 s: the images carry them
        self.reports = 0
        self.others = 0
        self.unreadable = 0
        self.no_heading = 0
        self.unmeasured = 0

    def feed(self, line: str, now_s: float) -> None:
        from pyais.messages import NMEAMessage

        start = sentence_start(line)
        if start < 0:
            return
        try:
            message = NMEAMessage.from_string(line[start:].strip())
            if not message.is_valid or message.frag_cnt != 1:
                if message.is_valid:
                    return                   # multi-part: static data, not a position
                raise ValueError("checksum")
            fields = message.decode().asdict()
        except Exception:                    # pyais's errors are many types
            self.unreadable += 1
            if worth_saying(self.unreadable):
                self.track.warn(f"AIS: {self.unreadable} unreadable sentence(s) skipped")
            return
        own = line[start + 3:start + 6] == "VDO"
        identity = report_identity(fields)
        if identity is None:
            self.unreadable += 1
            return
        mmsi, kind = identity
        if (self.mmsi is not None and mmsi != self.mmsi) or (self.mmsi is None and not own):
            self.others += 1
            return
        if kind not in POSITION_TYPES:
            return
        position = report_position(fields)
        if position is None:
            return
        unmeasured = unmeasured_position(fields)
        if unmeasured is not None:      # a frozen position must not keep the source fresh
            self.unmeasured += 1
            if worth_saying(self.unmeasured):
                self.track.warn(f"AIS: {self.unmeasured} position report(s) not from a working "
                                f"position fix skipped (the last: {unmeasured})")
            return
        heading, _ = report_heading(fields, self.allow_cog_heading)
        sog, cog = report_motion(fields)
        if heading is None:
            self.no_heading += 1
            if worth_saying(self.no_heading, every=None):
                self.track.warn(f"AIS: {self.no_heading} report(s) without a true heading "
                                "(511) skipped (--allow-cog-heading takes the course)")
            return
        now_utc = datetime.fromtimestamp(time.time(), UTC)
        fix = fix_time(now_utc, fields.get("second"))
        t_s = self.track.clock.observe(fix.timestamp(), now_s)
        self.track.add_position(t_s, *position, sog_mps=sog, cog_deg=cog,
                                rot_deg_s=report_turn(fields))
        self.track.add_heading(t_s, heading % 360.0)
        self.reports += 1
        if self.on_fix is not None:
            self.on_fix(now_s)
