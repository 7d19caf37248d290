"""A time series of positions (and attitudes or headings) read from one log, and its sampling.

Every reader returns a :class:`Track`: sample times ``t_s`` in seconds on the log's own clock,
``utc_start`` (the UTC time of ``t_s = 0``) where the log says it, and per-sample arrays.
Missing quantities are ``None``, never zeros.

Sampling at other times interpolates linearly between the two neighbouring samples: latitude
and longitude directly (the step between samples is metres, where a degree is locally
linear), angles and longitude on their unwrapped sequence (so 359 deg -> 1 deg passes through
0, not 180, and a track across the antimeridian stays near ±180 deg).
A time between two samples more than ``2 max_gap_s`` apart, or outside the track by more than
half its end sample interval (or ``max_gap_s``, if less), has no value: NaN, and the caller
reports the frame instead of guessing. (Outside, the end sample's value is held, not
extrapolated: GPS noise makes a slope from two samples worse than holding for half a step.)

Dead reckoning. A vessel track whose positions come with speed and course over ground (AIS:
a class A transponder reports every 10 s under way, 2-6 s when turning) sets
``dead_reckon_s``; where no sample is within reach of a time, but a position with speed and
course lies at most ``dead_reckon_s`` before it, the position is carried forward along the
course, ``p0 + sog · (t - t0) · (sin cog, cos cog)`` on the local east-north plane (or back
from the next one within ``dead_reckon_s`` after it), and where both are near, the two are
blended, weighted by nearness: ``(1 - w) p0' + w p1'``, ``w = (t - t0) / (t1 - t0)`` (where
a report was missed and the two do not both reach the whole gap, ``w`` tapers to 0 and 1
where each comes into and leaves reach, so the position does not jump: :func:`_blend_weight`).
Beyond ``dead_reckon_s`` of any report, up to ``frame_reach_s`` (AIS: a class B transponder
reports every 3 min under 2 kn), a time still gets the nearest report's position carried
alone, its age said, never blended: a blend with a report minutes away put a frame a second
from the last report at 13 s of age. Such a frame is not measured with its own pose.
A report at rest (speed under :data:`AT_REST_MPS`) without a course (AIS 360) carries its
position in place. A position reported without speed or course (an AIS report whose fields
are "not available", an RMC without them) is still an anchor: it is carried with the speed
and course of the nearest report that has them on the side carried to (else the other),
within reach, and its age counts that report's lag: ``sqrt(dt (dt + 2 lag))``, the time over
which a steady acceleration would err as much.
The heading is turned the short way between the reports around it, or the last one's held
where none follows yet (live), turned at its rate of turn where the report gives one.
``sample`` then says for how long in
``dead_reckoned_s`` (for the blend, ``sqrt((1 - w) dt0² + w dt1²)``: ``sqrt(dt0 dt1)`` with
the linear weight, exactly the blend's error under a steady acceleration), which the error
bars widen by (:func:`harborsight.geometry.sensor_sigmas.dead_reckoning_drift`).

Accuracy figures the log states go with the samples and are sampled the same way (never
unwrapped): ``position_sigma_m``, one sigma per horizontal axis (east, north) in metres;
``alt_sigma_m``, one sigma of ``alt_m`` in metres; ``heading_sigma_deg`` (vessel tracks). NaN
marks a sample without one; None, a log that states none. Where each comes from is in
``notes`` (:mod:`harborsight.telemetry.accuracy` turns a log's figures into these).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

#: The quantities a track may carry, each an array over samples or None.
QUANTITIES = ("lat_deg", "lon_deg", "alt_m", "yaw_deg", "pitch_deg", "roll_deg", "heading_deg",
              "position_sigma_m", "alt_sigma_m", "heading_sigma_deg", "focal_35mm_mm",
              "digital_zoom", "sog_mps", "cog_deg", "rot_deg_s")
#: the accuracy figures among them (one sigma; see the module docstring)
SIGMAS = ("position_sigma_m", "alt_sigma_m", "heading_sigma_deg")
ANGLES = frozenset({"yaw_deg", "pitch_deg", "roll_deg", "heading_deg", "cog_deg"})
#: quantities that change in steps, sampled at the nearest sample rather than interpolated
#: (a zoom between 24 and 48 mm is either, never 24.2 mm)
STEPS = frozenset({"focal_35mm_mm", "digital_zoom"})
#: Quantities that may run on their own time axis (``attitude_t_s``): autopilots log attitude
#: 10-50 times as often as position, and a gyrocompass sends heading more often than a GNSS
#: receiver sends fixes.
ATTITUDE = ("yaw_deg", "pitch_deg", "roll_deg")
ORIENTATION = (*ATTITUDE, "heading_deg", "heading_sigma_deg")

#: the window (s) of headings a rate of turn is fitted to where a log gives none
HEADING_RATE_WINDOW_S = 3.0
#: the least one-sigma (deg/s) of such a rate
HEADING_RATE_MIN_SIGMA_DEG_S = 0.05


@dataclass
class Track:
    """Samples of one log. ``attitude_of`` says what yaw/pitch/roll describe: ``"gimbal"``
    (the camera, DJI's G.PRY) or ``"vehicle"`` (the airframe's body FRD axes). Attitude
    and heading samples are at ``attitude_t_s`` where given, else at ``t_s``."""

    source: Path
    kind: str                                # dji-srt, px4-ulog, ardupilot-bin, nmea, csv
    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray | None = None
    alt_reference: str | None = None         # what alt_m is measured from, in words
    yaw_deg: np.ndarray | None = None
    pitch_deg: np.ndarray | None = None
    roll_deg: np.ndarray | None = None
    attitude_of: str | None = None
    attitude_t_s: np.ndarray | None = None
    heading_deg: np.ndarray | None = None    # vessel tracks: true heading
    position_sigma_m: np.ndarray | None = None   # one sigma per horizontal axis, m
    alt_sigma_m: np.ndarray | None = None        # one sigma of alt_m, m
    heading_sigma_deg: np.ndarray | None = None  # one sigma of heading_deg, deg
    #: the camera's focal length as its 35 mm equivalent, where the log states it (a DJI
    #: SRT's ``focal_len``): a zoom changes the intrinsics (:func:`zoom_reason`)
    focal_35mm_mm: np.ndarray | None = None
    #: the ratio of a digital zoom (a centre crop of the sensor, enlarged), where the log
    #: states it (a DJI SRT's ``dzoom_ratio`` or ``DZOOM``): the intrinsics scale with it
    #: (:func:`~harborsight.telemetry.metadata.digitally_zoomed`)
    digital_zoom: np.ndarray | None = None
    #: speed (m/s) and course (deg true) over ground with each position, where the log
    #: states them (AIS reports): what :meth:`sample` carries a position forward with
    sog_mps: np.ndarray | None = None
    cog_deg: np.ndarray | None = None
    #: rate of turn (deg/s, clockwise) with each position, where the log states it (an AIS
    #: report's ROT): a heading held past the last report turns with it
    rot_deg_s: np.ndarray | None = None
    #: how long (s) past a position its speed and course may carry it where no sample is
    #: within reach (module docstring, "Dead reckoning"); 0: never
    dead_reckon_s: float = 0.0
    #: how far (s) from a report a time still gets a position, carried from the nearest
    #: report alone, where none is within ``dead_reckon_s`` (``dead_reckoned_s`` then says
    #: more than that: not measured with, but carried by the images,
    #: :mod:`harborsight.flight.pose_carry`); 0: no further than ``dead_reckon_s``
    frame_reach_s: float = 0.0
    utc_start: datetime | None = None        # UTC time of t_s = 0, when the log states it
    clock: str = ""                          # what t_s counts, in words
    notes: list[str] = field(default_factory=list)   # lines skipped, fields missing, ...

    def __post_init__(self) -> None:
        self.t_s = np.asarray(self.t_s, dtype=float)
        if self.attitude_t_s is not None:
            self.attitude_t_s = np.asarray(self.attitude_t_s, dtype=float)
        for name in QUANTITIES:
            values = getattr(self, name)
            if values is not None:
                values = np.asarray(values, dtype=float)
                n = len(self._times_of(name))
                if values.shape != (n,):
                    raise ValueError(f"{name}: {values.shape} samples against {n} times")
                setattr(self, name, values)
        for axis in ("t_s", "attitude_t_s"):
            times = getattr(self, axis)
            if times is None or not len(times) or not np.any(np.diff(times) < 0):
                continue
            order = np.argsort(times, kind="stable")
            setattr(self, axis, times[order])
            for name in QUANTITIES:
                values = getattr(self, name)
                if values is not None and self._axis_of(name) == axis:
                    setattr(self, name, values[order])
            self.notes.append(f"{axis}: samples were out of time order and have been sorted")

    def _axis_of(self, name: str) -> str:
        return "attitude_t_s" if name in ORIENTATION and self.attitude_t_s is not None else "t_s"

    def _times_of(self, name: str) -> np.ndarray:
        return getattr(self, self._axis_of(name))

    def __len__(self) -> int:
        return len(self.t_s)

    def heading_rate(self, times_s: np.ndarray, window_s: float = HEADING_RATE_WINDOW_S
                     ) -> tuple[np.ndarray, np.ndarray]:
        """The rate of turn (deg/s, clockwise) at ``times_s`` from the headings themselves,
        and its sigma: the least-squares slope of the unwrapped headings within
        ``window_s / 2`` of each time, ``Σ(t - t̄)(h - h̄) / Σ(t - t̄)²``, its sigma the
        residuals' RMS over ``sqrt(Σ(t - t̄)²)`` (at least :data:`HEADING_RATE_MIN_SIGMA_DEG_S`:
        a heading given to 0.1° at 1 Hz); NaN where fewer than 3 headings span half the
        window. For logs that give no rate of turn (an HDT without a ROT)."""
        times_s = np.atleast_1d(np.asarray(times_s, dtype=float))
        rate = np.full(times_s.shape, np.nan)
        sigma = np.full(times_s.shape, np.nan)
        if self.heading_deg is None:
            return rate, sigma
        t = self._times_of("heading_deg")
        finite = np.isfinite(self.heading_deg)
        t, h = t[finite], np.rad2deg(np.unwrap(np.deg2rad(self.heading_deg[finite])))
        # each time's window by bisection (the times are sorted): a slice, not a mask of them all
        lo = np.searchsorted(t, times_s - window_s / 2, side="left")
        hi = np.searchsorted(t, times_s + window_s / 2, side="right")
        for k, (first, stop) in enumerate(zip(lo.tolist(), hi.tolist(), strict=True)):
            if stop - first < 3 or t[stop - 1] - t[first] < window_s / 2:
                continue
            tk, hk = t[first:stop], h[first:stop]
            lead = tk - tk.mean()
            spread = float(np.sum(lead * lead))
            slope = float(np.sum(lead * (hk - hk.mean()))) / spread
            residual = hk - hk.mean() - slope * lead
            scatter = math.sqrt(float(np.sum(residual * residual)) / max(len(tk) - 2, 1))
            rate[k] = slope
            sigma[k] = max(scatter / math.sqrt(spread), HEADING_RATE_MIN_SIGMA_DEG_S)
        return rate, sigma

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) if len(self) else 0.0

    @property
    def has_attitude(self) -> bool:
        return self.yaw_deg is not None and self.pitch_deg is not None

    def utc_at(self, t_s: float) -> datetime | None:
        """The UTC time of ``t_s`` on this track's clock, if the log states its UTC start."""
        return None if self.utc_start is None else self.utc_start + timedelta(seconds=float(t_s))

    def seconds_of(self, utc: datetime) -> float:
        """``t_s`` of a UTC time (needs ``utc_start``)."""
        if self.utc_start is None:
            raise ValueError(f"{self.source}: the log states no UTC time")
        return (utc - self.utc_start).total_seconds()

    def sample(self, times_s: np.ndarray, max_gap_s: float = 1.0,
               hold_s: float | None = None) -> dict[str, np.ndarray]:
        """Each present quantity at ``times_s`` (same clock as ``t_s``), NaN where the
        bracketing samples are more than ``2 max_gap_s`` apart, or the time lies outside the
        samples by more than half the end interval (at most ``max_gap_s``), or by more than
        ``hold_s`` where given (a live feed, whose newest sample is up to one interval older
        than the newest frame, holds it for that long)."""
        times_s = np.atleast_1d(np.asarray(times_s, dtype=float))
        out: dict[str, np.ndarray] = {}
        for name in QUANTITIES:
            values = getattr(self, name)
            if values is None:
                continue
            t = self._times_of(name)
            finite = np.isfinite(values)
            t, v = t[finite], values[finite]
            if len(t) == 0:
                out[name] = np.full(times_s.shape, np.nan)
                continue
            if name in STEPS:
                after = np.clip(np.searchsorted(t, times_s), 1, max(len(t) - 1, 1))
                before = after - 1
                nearer = np.where(np.abs(times_s - t[before]) <= np.abs(t[np.minimum(after, len(t) - 1)]
                                                                       - times_s), before, after)
                sampled = v[np.minimum(nearer, len(t) - 1)]
                out[name] = np.where(_reachable(t, times_s, max_gap_s, hold_s), sampled, np.nan)
                continue
            wraps = name in ANGLES or name == "lon_deg"
            if wraps:
                v = np.rad2deg(np.unwrap(np.deg2rad(v)))
            sampled = np.interp(times_s, t, v)
            if wraps:
                sampled = (sampled + 180.0) % 360.0 - 180.0
            out[name] = np.where(_reachable(t, times_s, max_gap_s, hold_s), sampled, np.nan)
        if self.dead_reckon_s > 0 and self.sog_mps is not None and self.cog_deg is not None:
            self._dead_reckon(times_s, out)
        return out

    def _dead_reckon(self, times_s: np.ndarray, out: dict[str, np.ndarray]) -> None:
        """Fill the positions ``sample`` found no sample within reach for, or held past the
        track's ends, where a position with speed and course lies at most ``dead_reckon_s``
        away (module docstring);
        ``out["dead_reckoned_s"]`` says for how long (0 where not dead-reckoned)."""
        import pymap3d

        t = self.t_s
        # a vessel at rest reports no course (AIS 360): its step is nil whatever the course
        course_deg = np.where(np.isfinite(self.cog_deg), self.cog_deg, 0.0)
        placed = np.isfinite(self.lat_deg) & np.isfinite(self.lon_deg)
        moving = placed & carried_by_motion(self.sog_mps, self.cog_deg)
        reach = self.dead_reckon_s

        def motion_of(k: int, forward: bool) -> tuple[float, float, float] | None:
            """Speed, course (rad) and their lag (s) to carry report ``k`` forward or back
            with: its own (lag 0), or, for a position reported without them, those of the
            nearest report with them on the side carried to (else the other side) within
            reach of it: a fix is still an anchor, and the choice does not change along the
            carry."""
            if moving[k]:
                return float(self.sog_mps[k]), float(np.deg2rad(course_deg[k])), 0.0
            near = moving & (np.abs(t - t[k]) <= reach)
            ahead = np.flatnonzero(near & ((t > t[k]) if forward else (t < t[k])))
            behind = np.flatnonzero(near & ((t < t[k]) if forward else (t > t[k])))
            pool = ahead if len(ahead) else behind
            if not len(pool):
                return None
            j = pool[np.argmin(np.abs(t[pool] - t[k]))]
            return (float(self.sog_mps[j]), float(np.deg2rad(course_deg[j])),
                    float(abs(t[j] - t[k])))

        age = np.zeros(times_s.shape)
        # where nothing is within reach, and past the track's ends (where sample holds the
        # end value: a moving vessel is better carried)
        todo = ~np.isfinite(out["lat_deg"]) | (times_s > t[-1]) | (times_s < t[0])
        for i in np.flatnonzero(todo):
            x = times_s[i]
            after = int(np.searchsorted(t, x, side="right"))
            before = after - 1
            ends = [(k, x - t[k], motion) for k in (before, after)   # carried forward, back
                    if 0 <= k < len(t) and placed[k] and abs(x - t[k]) <= reach
                    and (motion := motion_of(k, x >= t[k])) is not None]
            beyond = not ends and self.frame_reach_s > reach
            if beyond:                                      # the nearest report alone
                ends = sorted(((k, x - t[k], motion) for k in (before, after)
                               if 0 <= k < len(t) and placed[k]
                               and abs(x - t[k]) <= self.frame_reach_s
                               and (motion := motion_of(k, x >= t[k])) is not None),
                              key=lambda end: abs(end[1]))[:1]
            if not ends:
                continue
            guesses, ages = [], []
            for k, dt, (speed, course, lag) in ends:
                step = speed * dt
                guesses.append(pymap3d.enu2geodetic(step * np.sin(course), step * np.cos(course),
                                                    0.0, self.lat_deg[k], self.lon_deg[k], 0.0)[:2])
                # a motion from ``lag`` away: a steady acceleration's error grows as over a
                # carry of sqrt(dt (dt + 2 lag)) (module docstring)
                ages.append(math.sqrt(abs(dt) * (abs(dt) + 2.0 * lag)))
            if len(ends) == 1:
                out["lat_deg"][i], out["lon_deg"][i] = guesses[0]
                age[i] = ages[0]
            else:       # the two blended by nearness (module docstring)
                dt0, dt1 = x - t[before], t[after] - x
                w = _blend_weight(dt0, dt1, reach)
                east, north, _ = pymap3d.geodetic2enu(*guesses[1], 0.0, *guesses[0], 0.0)
                out["lat_deg"][i], out["lon_deg"][i] = pymap3d.enu2geodetic(
                    w * east, w * north, 0.0, *guesses[0], 0.0)[:2]
                age[i] = math.sqrt((1.0 - w) * ages[0] ** 2 + w * ages[1] ** 2)
            if "heading_deg" in out and beyond:    # that report's heading, and its turn
                k, dt = ends[0][0], ends[0][1]
                out["heading_deg"][i] = (self._heading_near(t[k])
                                         + self._turn_rate_at(t[k]) * max(dt, 0.0)) % 360.0
            elif "heading_deg" in out and not np.isfinite(out["heading_deg"][i]):
                out["heading_deg"][i] = self._heading_near(x)
            elif "heading_deg" in out and len(ends) == 1:
                out["heading_deg"][i] = self._heading_near(x)     # held from the nearest
        out["dead_reckoned_s"] = age

    def _heading_near(self, x: float) -> float:
        """The vessel's heading at ``x`` from the samples within ``dead_reckon_s``: between
        the last before and the first after it, turned the short way, weighted by time;
        the last before, held, where none follows; NaN where none is near."""
        if self.heading_deg is None:
            return math.nan
        times = self._times_of("heading_deg")
        near = np.isfinite(self.heading_deg) & (np.abs(times - x) <= self.dead_reckon_s)
        before = np.flatnonzero(near & (times <= x))
        after = np.flatnonzero(near & (times > x))
        if not len(before):
            return float(self.heading_deg[after[0]]) if len(after) else math.nan
        h0, t0 = float(self.heading_deg[before[-1]]), float(times[before[-1]])
        if not len(after):                  # held, turned at the reported rate of turn
            return (h0 + self._turn_rate_at(t0) * (x - t0)) % 360.0
        h1, t1 = float(self.heading_deg[after[0]]), float(times[after[0]])
        turn = (h1 - h0 + 180.0) % 360.0 - 180.0
        return (h0 + turn * (x - t0) / (t1 - t0)) % 360.0

    def _turn_rate_at(self, t: float) -> float:
        """The rate of turn (deg/s) the position sample at ``t`` states, else 0."""
        if self.rot_deg_s is None:
            return 0.0
        at = np.flatnonzero(np.isclose(self.t_s, t, rtol=0.0, atol=1e-6))
        rate = float(self.rot_deg_s[at[-1]]) if len(at) else math.nan
        return rate if math.isfinite(rate) else 0.0

    def summary(self) -> dict:
        """What an operator checks first: extent in time and space, rate, attitude, and the
        range of the accuracy figures the log states (None where it states none)."""
        def span(values: np.ndarray | None) -> list[float] | None:
            if values is None or not np.isfinite(values).any():
                return None
            return [float(np.nanmin(values)), float(np.nanmax(values))]

        rate = (len(self) - 1) / self.duration_s if self.duration_s > 0 else None
        return {
            "source": str(self.source), "kind": self.kind, "samples": len(self),
            "duration_s": self.duration_s, "rate_hz": rate, "clock": self.clock,
            "utc_start": None if self.utc_start is None else self.utc_start.isoformat(),
            "lat_deg": span(self.lat_deg), "lon_deg": span(self.lon_deg),
            "alt_m": span(self.alt_m), "alt_reference": self.alt_reference,
            "attitude": None if not self.has_attitude else self.attitude_of,
            "heading": self.heading_deg is not None,
            **{name: span(getattr(self, name)) for name in SIGMAS}, "notes": list(self.notes),
        }


#: a speed over ground (m/s) under which a position without a course is carried in place
AT_REST_MPS = 0.05
#: how long (s) a position's speed and course carry the vessel where the positions stop (an
#: NMEA receiver or a Signal K source that loses its fix for a few seconds, under a crane)
POSITION_GAP_DEAD_RECKON_S = 5.0
#: 1 knot in m/s (AIS and NMEA give speeds in knots)
KNOT_MPS = 1852.0 / 3600.0


def carried_by_motion(sog_mps, cog_deg):
    """Whether a position with this speed (m/s) and course (deg) can be carried: both given,
    or a speed at rest (:data:`AT_REST_MPS`) without a course (AIS 360). Arrays or numbers."""
    sog, cog = np.asarray(sog_mps, float), np.asarray(cog_deg, float)
    return np.isfinite(sog) & (np.isfinite(cog) | (sog < AT_REST_MPS))


def _blend_weight(dt0: float, dt1: float, reach_s: float) -> float:
    """The weight of the position carried back from the next report (module docstring):
    ``dt0 / (dt0 + dt1)`` where both reports reach the whole gap; where they do not (a
    report missed), ``dt0 (R - dt1) / (dt0 (R - dt1) + dt1 (R - dt0))``, which is 0 where
    the next one comes into reach and 1 where the last one leaves it."""
    if dt0 + dt1 <= reach_s:
        return dt0 / (dt0 + dt1)
    forward, back = dt1 * (reach_s - dt0), dt0 * (reach_s - dt1)
    return back / (forward + back) if forward + back > 0 else 0.5


def _reachable(t: np.ndarray, times_s: np.ndarray, max_gap_s: float,
               hold_s: float | None = None) -> np.ndarray:
    """Where interpolation in the samples ``t`` is trusted (see :meth:`Track.sample`)."""
    index = np.searchsorted(t, times_s)
    before = t[np.clip(index - 1, 0, len(t) - 1)]
    after = t[np.clip(index, 0, len(t) - 1)]
    inside = (times_s >= t[0]) & (times_s <= t[-1])
    # outside, the end value is held: for at most half the last sample interval
    first_step = t[1] - t[0] if len(t) > 1 else 0.0
    last_step = t[-1] - t[-2] if len(t) > 1 else 0.0
    if hold_s is not None:
        reach = np.full(times_s.shape, float(hold_s))
    else:
        reach = np.where(times_s < t[0], min(max_gap_s, first_step / 2),
                         min(max_gap_s, last_step / 2))
    outside_ok = np.minimum(np.abs(times_s - t[0]), np.abs(times_s - t[-1])) <= reach
    return np.where(inside, (after - before <= 2 * max_gap_s) | (times_s == before)
                    | (times_s == after), outside_ok)


#: a second source interpolated onto a track's sample times (an altitude topic, an
#: autopilot's estimated altitude) gives NaN at a time whose two source samples around it
#: are more than this many of the source's median sample intervals apart: the gap then
#: shows in the track, and :meth:`Track.sample` judges it by its own rule (``max_gap_s``)
#: instead of a straight line drawn across it
SOURCE_GAP_INTERVALS = 3.0
#: ... and never a gap shorter than this (s): a source stamped on arrival comes in bursts
#: with repeated times, whose median interval is near 0
SOURCE_GAP_FLOOR_S = 0.5


def interpolate_source(times_s: np.ndarray, source_t_s: np.ndarray, source_values: np.ndarray
                       ) -> tuple[np.ndarray, float | None]:
    """``source_values`` (at the increasing ``source_t_s``) at ``times_s``: linear between
    the two source samples around a time, NaN outside the source's span and across a gap of
    more than :data:`SOURCE_GAP_INTERVALS` median intervals (of those above 0) and
    :data:`SOURCE_GAP_FLOOR_S`. Returns the values and the
    longest such gap that held a time (s; None when none did)."""
    times_s = np.asarray(times_s, dtype=float)
    values = np.interp(times_s, source_t_s, source_values, left=np.nan, right=np.nan)
    if len(source_t_s) < 2:
        return values, None
    steps = np.diff(source_t_s)
    steps = steps[steps > 1e-6]
    if not len(steps):
        return values, None
    limit = max(SOURCE_GAP_INTERVALS * float(np.median(steps)), SOURCE_GAP_FLOOR_S)
    after = np.clip(np.searchsorted(source_t_s, times_s, side="right"), 1, len(source_t_s) - 1)
    span = source_t_s[after] - source_t_s[after - 1]
    on_sample = (times_s == source_t_s[after]) | (times_s == source_t_s[after - 1])
    gap = (span > limit) & ~on_sample & np.isfinite(values)
    values[gap] = np.nan
    return values, (float(span[gap].max()) if gap.any() else None)


def utc_from_epoch_s(seconds: float) -> datetime:
    return datetime.fromtimestamp(float(seconds), tz=UTC)
