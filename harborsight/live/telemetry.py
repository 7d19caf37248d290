"""Live telemetry: drone and vessel samples as they arrive, on one clock, and a frame's
``harborsight.frame/1`` metadata composed from them at the frame's time.

Clocks. Every feed stamps its samples on its own clock: MAVLink on the autopilot's boot time,
NMEA on the fix's UTC time. :class:`ClockMap` places them on this process's monotonic clock
with ``offset = min(arrival − source time)`` over the last ``window`` samples: transport
delays only ever add, so the least-delayed sample gives the best estimate of the difference
(the one-way half of NTP's filter), and jitter does not reach the samples' times. A sample
whose offset lies more than ``jump_s`` from the estimate means the source's clock jumped (a
reboot, a GPS time fix, a replay restarted): the estimate starts again from it and the jump
is counted. A source's own delay (a GNSS receiver that sends its fix 0.2 s after the epoch)
is a configurable ``offset_s`` added to its mapped times.

A frame's time is its arrival (its timestamp mapped by a :class:`ClockMap` of its own in
:mod:`harborsight.live.video_in`) less ``video_delay_s`` (encoder, link and decoder; a DJI or
RTSP feed is 0.1-0.5 s behind). Drone and vessel are sampled there by
:func:`harborsight.telemetry.metadata.frames_at_times` (linear interpolation, angles
unwrapped: :meth:`harborsight.telemetry.track.Track.sample`). The newest sample of a feed is
usually older than the newest frame, so it is held for up to ``hold_s`` (default 1 s; the
pose refinement absorbs the few decimetres a berthing ship moves in that time); a frame later
than that is not measured and the reason is shown. A vessel from AIS, whose reports come
every 10 s, is carried by each report's speed and course for up to 12 s instead
(:mod:`harborsight.telemetry.track`, "Dead reckoning"), its error bars widened for the time.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from harborsight.errors import HarborsightError
from harborsight.telemetry.metadata import CameraMount, frames_at_times
from harborsight.telemetry.track import Track

#: seconds of samples a live track keeps (interpolation needs the last few only)
HORIZON_S = 30.0
#: a sample this much older than the newest held is said when left out (less is jitter)
LATE_SAID_S = 1.0


@dataclass
class ClockMap:
    """Maps a source's clock to the monotonic clock (module docstring)."""

    window: int = 64
    jump_s: float = 2.0
    offset_s: float = 0.0                 # added to every mapped time (the source's own delay)
    jumps: int = 0
    _offsets: deque = field(default_factory=deque, repr=False)
    _best: float | None = field(default=None, repr=False)

    def observe(self, source_s: float, arrival_s: float) -> float:
        """Record a sample that arrived at ``arrival_s`` stamped ``source_s``; its time on the
        monotonic clock."""
        offset = arrival_s - source_s
        if self._best is not None and abs(offset - self._best) > self.jump_s:
            self._offsets.clear()
            self.jumps += 1
        self._offsets.append(offset)
        if len(self._offsets) > self.window:
            self._offsets.popleft()
        self._best = min(self._offsets)
        return source_s + self._best + self.offset_s

    def to_local(self, source_s: float) -> float | None:
        return None if self._best is None else source_s + self._best + self.offset_s

    def to_source(self, local_s: float) -> float | None:
        return None if self._best is None else local_s - self._best - self.offset_s


class SenderClocks(dict):
    """One :class:`ClockMap` per sender on a feed (a Signal K source, a MAVLink system and
    component), each sender stamping by its own clock; the primary sender's (the one whose
    positions the track holds) is the track's own map, through which frames get their UTC."""

    def __init__(self, track: LiveTrack) -> None:
        super().__init__()
        self.track = track

    @property
    def has_primary(self) -> bool:
        return any(clock is self.track.clock for clock in self.values())

    def of(self, sender, primary: bool) -> ClockMap:
        """``sender``'s map; the track's own when ``primary`` and no sender has it yet."""
        clock = self.get(sender)
        if primary and clock is not self.track.clock and not self.has_primary:
            clock = self[sender] = self.track.clock
        elif clock is None:
            clock = self[sender] = ClockMap()
        return clock

    def primary_or_unknown(self, sender) -> bool:
        """Whether ``sender`` is the primary one, or none is known yet."""
        return self.get(sender) is self.track.clock or not self.has_primary


def worth_saying(count: int, every: int | None = 1000) -> bool:
    """Whether the ``count``-th of a repeated warning is said: the 1st, 10th and 100th, and
    then every ``every``-th (None: no more), so a flood is heard without drowning the log."""
    return count in (1, 10, 100) or (every is not None and count % every == 0)


class LiveTrack:
    """A feed's samples of the last ``HORIZON_S`` seconds on the monotonic clock, written by
    the feed's reader thread and read as a :class:`Track` by the measuring loop."""

    def __init__(self, source: str, kind: str, *, alt_reference: str | None = None) -> None:
        self.source, self.kind, self.alt_reference = source, kind, alt_reference
        self.clock = ClockMap()
        self.utc_clock: ClockMap | None = None     # source seconds -> UTC epoch, where known
        self.attitude_of: str | None = None
        self._positions: deque = deque()           # (t, lat, lon, alt, sigma, sog, cog, rot)
        #: how long a position's speed and course may carry it (Track.dead_reckon_s; AIS),
        #: and how far a frame still gets the nearest one's (Track.frame_reach_s)
        self.dead_reckon_s = 0.0
        self.frame_reach_s = 0.0
        self._orientation: deque = deque()         # (t, yaw, pitch, roll) or (t, heading)
        self._lock = threading.Lock()
        #: samples left out for coming more than LATE_SAID_S after newer ones
        self.late_samples = 0
        #: called with (source name, message) for every warning (the dashboard and the log)
        self.on_warning: Callable[[str, str], None] | None = None

    def source_clock_is_utc(self) -> None:
        """The feed's own times are UTC epoch seconds (NMEA fixes, AIS, Signal K updates)."""
        self.utc_clock = ClockMap()
        self.utc_clock.observe(0.0, 0.0)

    def warn(self, message: str) -> None:
        if self.on_warning is not None:
            self.on_warning(self.source, message)

    @staticmethod
    def _trim(samples: deque, newest_s: float) -> None:
        while samples and samples[0][0] < newest_s - HORIZON_S:
            samples.popleft()

    def _append(self, samples: deque, row: tuple) -> None:
        """Add a sample in time order. One older than the newest held is left out (jitter
        past a sample, or a late copy from a second, lagging link), counted and said when
        it is more than :data:`LATE_SAID_S` late; it never clears what is held: a source
        whose clock jumps is restarted by its :class:`ClockMap`, whose mapped times then
        follow on."""
        late_s = 0.0
        with self._lock:
            if samples and row[0] < samples[-1][0]:
                late_s = samples[-1][0] - row[0]
                if late_s > LATE_SAID_S:
                    self.late_samples += 1
            elif samples and row[0] == samples[-1][0]:
                samples[-1] = row
            else:
                samples.append(row)
                self._trim(samples, row[0])
        if late_s > LATE_SAID_S and worth_saying(self.late_samples):
            self.warn(f"{self.late_samples} sample(s) that came more than {LATE_SAID_S:g} s after "
                      f"newer ones left out (the latest {late_s:.1f} s late: a second link?)")

    def add_position(self, t_s: float, lat_deg: float, lon_deg: float, alt_m: float = math.nan,
                     sigma_m: float = math.nan, sog_mps: float = math.nan,
                     cog_deg: float = math.nan, rot_deg_s: float = math.nan) -> None:
        self._append(self._positions, (t_s, lat_deg, lon_deg, alt_m, sigma_m, sog_mps, cog_deg,
                                       rot_deg_s))

    def add_motion(self, t_s: float, sog_mps: float, cog_deg: float) -> None:
        """The speed and course of the position held at ``t_s`` (an NMEA epoch's RMC after
        its GGA); nothing where the newest position is of another time."""
        with self._lock:
            if self._positions and self._positions[-1][0] == t_s:
                row = self._positions[-1]
                self._positions[-1] = (*row[:5], sog_mps, cog_deg, *row[7:])

    def add_turn(self, t_s: float, rot_deg_s: float) -> None:
        """The rate of turn (deg/s) of the position held at ``t_s`` (an NMEA ROT after the
        epoch's fix); nothing where the newest position is of another time."""
        with self._lock:
            if self._positions and self._positions[-1][0] == t_s:
                row = self._positions[-1]
                self._positions[-1] = (*row[:7], rot_deg_s)

    def add_attitude(self, t_s: float, yaw_deg: float, pitch_deg: float, roll_deg: float,
                     of: str) -> None:
        """Camera (``gimbal``) or airframe (``vehicle``) attitude; a gimbal's replaces the
        airframe's once it is heard (the camera's own is the one to measure with)."""
        with self._lock:
            if of == "vehicle" and self.attitude_of == "gimbal":
                return
            if of != self.attitude_of:
                self._orientation.clear()
                self.attitude_of = of
        self._append(self._orientation, (t_s, yaw_deg, pitch_deg, roll_deg))

    def add_heading(self, t_s: float, heading_deg: float) -> None:
        self._append(self._orientation, (t_s, heading_deg))

    @property
    def newest_position_s(self) -> float | None:
        with self._lock:
            return self._positions[-1][0] if self._positions else None

    def latest_position(self) -> tuple[float, float] | None:
        with self._lock:
            return self._positions[-1][1:3] if self._positions else None

    def track(self) -> Track | None:
        """The samples held now as a :class:`Track` (None before the first position)."""
        with self._lock:
            positions, orientation = list(self._positions), list(self._orientation)
            attitude_of = self.attitude_of
        if not positions:
            return None
        p = np.array(positions, dtype=float)
        o = (np.array(orientation, dtype=float) if orientation   # positions, no attitude yet
             else np.zeros((0, 0)))
        extra: dict = {}
        if len(o) and o.shape[1] == 4:
            extra = {"yaw_deg": o[:, 1], "pitch_deg": o[:, 2], "roll_deg": o[:, 3],
                     "attitude_of": attitude_of, "attitude_t_s": o[:, 0]}
        elif len(o):
            extra = {"heading_deg": o[:, 1], "attitude_t_s": o[:, 0]}
        alt = p[:, 3] if np.isfinite(p[:, 3]).any() else None
        sigma = p[:, 4] if np.isfinite(p[:, 4]).any() else None
        if np.isfinite(p[:, 5]).any():
            extra.update(sog_mps=p[:, 5], cog_deg=p[:, 6], dead_reckon_s=self.dead_reckon_s,
                         frame_reach_s=self.frame_reach_s,
                         rot_deg_s=p[:, 7] if np.isfinite(p[:, 7]).any() else None)
        return Track(source=Path(self.source), kind=self.kind, t_s=p[:, 0], lat_deg=p[:, 1],
                     lon_deg=p[:, 2], alt_m=alt, alt_reference=self.alt_reference,
                     position_sigma_m=sigma, clock="monotonic seconds of this process", **extra)


@dataclass
class FrameComposer:
    """A frame's metadata from the live drone and vessel tracks at the frame's time."""

    drone: LiveTrack
    vessel: LiveTrack
    #: the frame/1 camera block for a frame size (InputError where the calibration is of another)
    camera_for: Callable[[int, int], dict]
    water_level_m: float = 0.0
    mount: CameraMount = field(default_factory=CameraMount)
    video_delay_s: float = 0.0
    hold_s: float = 1.0
    max_gap_s: float = 1.0

    def frame_time_s(self, arrived_s: float) -> float:
        return arrived_s - self.video_delay_s

    def utc_at(self, t_s: float) -> datetime:
        """UTC of a monotonic time: from a feed that states UTC (the vessel's GNSS, the
        drone's SYSTEM_TIME), else this machine's clock."""
        for track in (self.vessel, self.drone):
            if track.utc_clock is not None:
                source_s = track.clock.to_source(t_s)
                epoch = None if source_s is None else track.utc_clock.to_local(source_s)
                if epoch is not None:
                    return datetime.fromtimestamp(epoch, tz=UTC)
        return datetime.now(UTC) - timedelta(seconds=time.monotonic() - t_s)

    def compose(self, frame_index: int, arrived_s: float, width: int, height: int
                ) -> tuple[dict | None, str | None]:
        """``(frame/1 dict, None)``, or ``(None, why not)``."""
        drone, vessel = self.drone.track(), self.vessel.track()
        if drone is None or vessel is None:
            missing = [name for name, track in (("drone", drone), ("vessel", vessel)) if track is None]
            return None, f"no {' or '.join(missing)} position received yet"
        if drone.alt_m is None:
            return None, "the drone's feed has no altitude"
        if not drone.has_attitude and self.mount.yaw_deg is None:
            return None, "no drone or camera attitude received yet"
        try:
            camera = self.camera_for(width, height)
        except HarborsightError as exc:
            return None, str(exc)
        t_s = self.frame_time_s(arrived_s)
        try:
            result = frames_at_times(drone, vessel, camera, np.array([t_s]), np.array([t_s]),
                                     [self.utc_at(t_s)], water_level_m=self.water_level_m,
                                     mount=self.mount, max_gap_s=self.max_gap_s,
                                     hold_s=self.hold_s, indices=[frame_index])
        except (ValueError, HarborsightError) as exc:     # a mount the feed cannot serve
            return None, str(exc)
        if not result.frames:
            return None, result.skipped[0][1]
        frame = result.frames[0]
        frame["image"] = f"live-{frame_index:06d}.jpg"
        frame["telemetry"].update({
            "drone_age_s": _age(drone, t_s), "vessel_age_s": _age(vessel, t_s)})
        return frame, None


def _age(track: Track, t_s: float) -> float:
    """How much older than ``t_s`` the track's newest position is (negative: newer)."""
    return round(float(t_s - track.t_s[-1]), 3)
