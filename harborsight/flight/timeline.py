"""Per-section clearance over time: closing speed, time to contact, the CSV and the plot.

Two estimates of each section's closing speed are kept side by side:

* **filtered** (``closing_speed_mps``, ``filtered_distance_m``, ``time_to_contact_s``): the
  gated per-section Kalman tracker of :mod:`harborsight.flight.tracking`, fed with each
  frame's distance and its sigma; robust to outliers, missing frames, sections entering and
  leaving the view, and obstacles that come and go (each gets its own track);
* **raw** (``closing_speed_raw_mps``): minus the least-squares slope of the distance over the
  samples of the last ``window_s`` seconds (at least ``min_samples`` of them):

      v_k(t) = -Σ (t_i - t̄)(d_i - d̄) / Σ (t_i - t̄)²,   t - window_s <= t_i <= t

A positive speed means the gap is shrinking. Time to contact is the filtered distance over
the filtered closing speed while that exceeds the tracker's ``min_closing_mps``.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict, deque
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from harborsight.clearance.report import STATUS_OK, ClearanceReport
from harborsight.errors import InputError
from harborsight.flight.stamps import StampResolution
from harborsight.flight.tracker_inputs import Reading, SectionEstimate, TrackerSettings, seen_clear
from harborsight.flight.tracking import SectionTracker
from harborsight.frame import FrameMetadata

CSV_COLUMNS = [
    "frame", "image", "timestamp", "time_s", "altitude_m", "gsd_m_per_px", "method", "section",
    "status", "distance_m", "sigma_m", "distance_lower_m", "distance_px", "contact", "truncated",
    "closing_speed_raw_mps", "filtered_distance_m", "filtered_sigma_m", "closing_speed_mps",
    "closing_speed_sigma_mps", "time_to_contact_s", "track", "track_state", "clear_to_m",
    "pose_contradicted", "hidden_to_m", "own_closing_mps",
]


def iso_seconds(text: str) -> float:
    """POSIX seconds of an ISO 8601 time (UTC when it names no zone); ValueError if bad."""
    if not isinstance(text, str):
        raise ValueError(f"expected an ISO 8601 string, got {text!r}")
    stamp = datetime.fromisoformat(text)
    return (stamp if stamp.tzinfo else stamp.replace(tzinfo=UTC)).timestamp()


def timestamp_seconds(meta: FrameMetadata) -> float | None:
    """POSIX seconds of the frame's ``timestamp`` (None without one)."""
    if meta.timestamp is None:
        return None
    try:
        return iso_seconds(meta.timestamp)
    except ValueError:
        raise InputError(meta.source, "timestamp",
                         f"not an ISO 8601 time: {meta.timestamp!r}") from None


def least_squares_slope(times_s: list[float], values: list[float]) -> float:
    """Slope of the least-squares line through ``(times_s, values)``."""
    n = len(times_s)
    t_mean = sum(times_s) / n
    v_mean = sum(values) / n
    spread = sum((t - t_mean) ** 2 for t in times_s)
    if spread <= 0:
        return math.nan
    return sum((t - t_mean) * (v - v_mean) for t, v in zip(times_s, values, strict=True)) / spread


@dataclass
class SectionTrend:
    """One section after a frame: the raw window fit and the tracker's estimate."""

    closing_speed_raw_mps: float | None = None
    estimate: SectionEstimate = field(default_factory=SectionEstimate)

    @property
    def closing_speed_mps(self) -> float | None:
        return self.estimate.closing_speed_mps

    @property
    def time_to_contact_s(self) -> float | None:
        return self.estimate.time_to_contact_s


@dataclass
class ClearanceTimeline:
    """Collects every measured frame; estimates each section's closing speed as it goes.

    Only sections with status ``ok`` and not ``truncated`` enter the fit: a truncated
    distance is an upper bound set by where the image edge falls, and the drone's drift would
    turn it into a speed. Frames must come in time order (equal times are fine). A frame
    whose time is before the previous frame's is measured but left out of the fits, with a
    warning. When ``resync_frames`` frames in a row are behind (and in order among
    themselves), it was the earlier time that was wrong (a glitch ahead, e.g. a bad GPS
    time): its samples are dropped from the fits, the run of frames joins them, and the clock
    follows the frames again. Once two frames in a row share a time (whole-second stamps at
    several frames a second), every frame's time is taken as anywhere within the clock's
    step, and the tracker is told so (``Reading.time_sigma_s``; noted once).
    """

    window_s: float = 2.0
    min_samples: int = 3
    resync_frames: int = 3
    tracker_settings: TrackerSettings = field(default_factory=TrackerSettings)
    rows: list[dict] = field(default_factory=list)
    _trackers: dict[int, SectionTracker] = field(default_factory=dict)
    _history: dict[int, deque] = field(default_factory=lambda: defaultdict(deque))
    _last_time_s: float | None = None
    _behind: list[tuple[int, float]] = field(default_factory=list)   # (frame, time_s)
    _off_clock_frames: set[int] = field(default_factory=set)
    _stamps: StampResolution = field(default_factory=StampResolution)

    def _place_in_time(self, frame_index: int, time_s: float) -> tuple[bool, str | None]:
        """Whether this frame's time can join the fits, and a warning when it cannot."""
        if self._last_time_s is None or time_s >= self._last_time_s:
            self._behind.clear()
            return True, None
        if self._behind and time_s < self._behind[-1][1]:
            self._behind.clear()            # only a run of frames in order can resync
        self._behind.append((frame_index, time_s))
        if len(self._behind) >= self.resync_frames:
            wrong_from = self._behind[0][1]
            behind_frames = {f for f, _ in self._behind}
            ahead = sorted({r["frame"] for r in self.rows if r["time_s"] is not None
                            and r["time_s"] > wrong_from and r["frame"] not in behind_frames})
            for history in self._history.values():
                while history and history[-1][0] > wrong_from:
                    history.pop()
            for row in self.rows:             # the run's earlier frames join the fits now
                if (row["frame"] in behind_frames and row["status"] == STATUS_OK
                        and not row["truncated"]):
                    self._history[row["section"]].append((row["time_s"], row["distance_m"]))
            self._off_clock_frames.update(ahead)
            self._off_clock_frames.difference_update(behind_frames)
            self._trackers.clear()          # the tracks ran on the wrong clock: start afresh
            self._stamps.restart()
            warning = (f"{len(self._behind)} frames in a row are before {self._last_time_s:.3f} s:"
                       f" the time of frame(s) {', '.join(map(str, ahead))} is taken as wrong, "
                       "left out of the closing speeds from here on, and the clock follows the "
                       "frames again")
            self._behind.clear()
            return True, warning
        self._off_clock_frames.add(frame_index)
        return False, (f"{time_s:.3f} s after the start is before the previous frame's "
                       f"{self._last_time_s:.3f} s: measured, but left out of the closing speeds")

    def add(self, frame_index: int, time_s: float | None, report: ClearanceReport
            ) -> tuple[dict[int, SectionTrend], list[dict], str | None]:
        """Record one frame's report (``time_s``: seconds since the flight's start, or None
        when unknown); returns every section's trend, the frame's CSV rows, and a warning
        when the frame's time is out of order (see the class docstring)."""
        timed, warning = (False, None) if time_s is None else self._place_in_time(frame_index,
                                                                                  time_s)
        time_sigma_s = 0.0
        if timed:
            time_sigma_s, note = self._stamps.observe(frame_index, time_s)
            warning = warning or note
        trends, rows = {}, []
        for section in report.sections:
            trend = SectionTrend()
            fits = (section.status == STATUS_OK and not section.truncated
                    and not report.sensors_contradicted)
            if timed:
                history = self._history[section.index]
                if fits:
                    history.append((time_s, section.distance_m))
                while history and history[0][0] < time_s - self.window_s:
                    history.popleft()
                if fits and len(history) >= self.min_samples:
                    times, distances = zip(*history, strict=True)
                    slope = least_squares_slope(list(times), list(distances))
                    if math.isfinite(slope):
                        trend.closing_speed_raw_mps = -slope
                tracker = self._trackers.setdefault(
                    section.index, SectionTracker(self.tracker_settings))
                reading = (Reading(section.distance_m, section.sigma_m, section.sigma_random_m,
                                   section.own_rate_mps, section.own_rate_sigma_mps, time_sigma_s)
                           if fits else None)
                trend.estimate = tracker.step(time_s, reading, seen_clear(section))
            trends[section.index] = trend
            estimate = trend.estimate
            rows.append({
                "frame": frame_index, "image": report.image, "timestamp": report.timestamp or "",
                "time_s": _round(time_s, 3), "altitude_m": round(report.altitude_m, 2),
                "gsd_m_per_px": round(report.gsd_m_per_px, 5), "method": report.method,
                "section": section.index, "status": section.status,
                "distance_m": _round(section.distance_m, 3),
                "sigma_m": _round(section.sigma_m, 3),
                "distance_lower_m": _round(section.distance_lower_m, 3),
                "distance_px": _round(section.distance_px, 2),
                "contact": int(section.contact), "truncated": int(section.truncated),
                "closing_speed_raw_mps": _round(trend.closing_speed_raw_mps, 3),
                "filtered_distance_m": _round(estimate.distance_m, 3),
                "filtered_sigma_m": _round(estimate.sigma_m, 3),
                "closing_speed_mps": _round(estimate.closing_speed_mps, 3),
                "closing_speed_sigma_mps": _round(estimate.closing_speed_sigma_mps, 3),
                "time_to_contact_s": _round(estimate.time_to_contact_s, 1),
                "track": estimate.track, "track_state": estimate.state if timed else "",
                "clear_to_m": _round(section.clear_to_m, 2),
                "pose_contradicted": int(report.sensors_contradicted),
                "hidden_to_m": _round(section.hidden_to_m, 2),
                "own_closing_mps": (None if section.own_rate_mps is None
                                    else _round(-section.own_rate_mps, 3)),
            })
        if timed:
            self._last_time_s = time_s
        self.rows.extend(rows)
        return trends, rows, warning

    @staticmethod
    def csv_writer(handle) -> csv.DictWriter:
        """A writer of :data:`CSV_COLUMNS` rows (header written); write rows as they come
        with :func:`write_rows`, so an interrupted run keeps what it measured."""
        writer = csv.DictWriter(handle, CSV_COLUMNS)
        writer.writeheader()
        return writer

    def plot(self, path: Path, alarm_m: float = 2.0, warn_m: float = 5.0) -> bool:
        """Distance of every section over time, and the closing speed of the closest one
        (with, where the frames give the vessel's velocity, the part its own motion makes).
        Returns False (and writes nothing) when no section was ever measured."""
        measured = [r for r in self.rows if r["distance_m"] is not None]
        if not measured:
            return False
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        on_clock = [r for r in measured
                    if r["time_s"] is not None and r["frame"] not in self._off_clock_frames]
        use_time = bool(on_clock)         # frames off the clock are left out of a time axis
        measured = on_clock if use_time else measured
        x_key, x_label = ("time_s", "time (s)") if use_time else ("frame", "frame")
        sections = sorted({r["section"] for r in measured})
        colours = plt.get_cmap("viridis")(
            [i / max(len(sections) - 1, 1) for i in range(len(sections))])
        fig, (ax_d, ax_v) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True,
                                         height_ratios=[2, 1], constrained_layout=True)
        for colour, k in zip(colours, sections, strict=True):
            rows = [r for r in measured if r["section"] == k]
            ax_d.plot([r[x_key] for r in rows], [r["distance_m"] for r in rows], ".", ms=3,
                      color=colour, label=f"section {k}")
            filtered = [r for r in rows if r["filtered_distance_m"] is not None]
            ax_d.plot([r[x_key] for r in filtered], [r["filtered_distance_m"] for r in filtered],
                      "-", lw=1.2, color=colour)
        ax_d.axhspan(0, alarm_m, color="tab:red", alpha=0.12, lw=0)
        ax_d.axhspan(alarm_m, warn_m, color="tab:orange", alpha=0.10, lw=0)
        ax_d.set_ylim(bottom=0)
        ax_d.set_ylabel("clearance (m)\n(dots: each frame; lines: filtered)")
        ax_d.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                    ncol=1 + len(sections) // 17)
        ax_d.grid(alpha=0.3)
        closest = {}
        for r in measured:
            best = closest.get(r["frame"])
            if best is None or r["distance_m"] < best["distance_m"]:
                closest[r["frame"]] = r
        rows = [closest[f] for f in sorted(closest) if closest[f]["closing_speed_mps"] is not None]
        x = [r[x_key] for r in rows]
        speed = np.array([r["closing_speed_mps"] for r in rows], float)
        spread = np.array([r["closing_speed_sigma_mps"] or 0.0 for r in rows], float)
        ax_v.fill_between(x, speed - spread, speed + spread, color="grey", alpha=0.25, lw=0,
                          label="± one sigma")
        ax_v.plot(x, speed, "k.-", ms=3, lw=1, label="filtered")
        own = [(r[x_key], r["own_closing_mps"]) for r in rows if r.get("own_closing_mps") is not None]
        if own:     # what the vessel's own motion alone makes of it (the frames' velocity)
            ax_v.plot(*zip(*own, strict=True), "--", color="tab:blue", lw=1,
                      label="the vessel's own motion")
        if rows:
            ax_v.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        ax_v.axhline(0, color="grey", lw=0.8)
        ax_v.set_ylabel("closing speed of the\nclosest section (m/s)")
        ax_v.set_xlabel(x_label)
        ax_v.grid(alpha=0.3)
        if not rows:
            ax_v.text(0.5, 0.5, "no closing speed" if use_time else
                      "no closing speed: frames need timestamps", ha="center",
                      va="center", transform=ax_v.transAxes, color="grey")
        fig.savefig(path, dpi=120)
        plt.close(fig)
        return True


def write_rows(writer: csv.DictWriter, rows: list[dict]) -> None:
    writer.writerows({k: "" if v is None else v for k, v in row.items()} for row in rows)


def _round(value: float | None, digits: int) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), digits)
