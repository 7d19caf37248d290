"""The live berthing aid's core: one frame in, the state the crew sees out.

:class:`LiveEngine` measures a frame (segmentation, clearance with pose refinement and
uncertainty), runs each section's tracker (filtered distance, closing speed, time to
contact), updates the alarms (:mod:`harborsight.live.alarms`) and the sources' health
(:mod:`harborsight.live.health`), and returns a ``harborsight.live/1`` state:

``schema``, ``time`` (UTC ISO 8601), ``frame_index``, ``frame_time`` (the measured frame's
timestamp), ``latency_ms`` (frame arrival to the
state; for a stream, from the arrival its timestamp gives, so a decoder's backlog
counts), ``vessel``, ``min_distance_m``, ``sections`` (each ``index``, ``status``
``ok``/``caution``/``danger``, or the measurement's status when it has no distance to
judge, e.g. ``out_of_view``; ``measured``, the measurement's own status; ``distance_m``,
``distance_lower_m``, ``sigma_m``, ``filtered_distance_m``, ``closing_speed_mps``,
``time_to_contact_s`` (these two only beside a current distance), ``level``, the alarm
level the section holds (``ok``/``caution``/``danger``, also while it has no measurement to
judge), ``alarm`` (bool) and ``stale``), ``alarms`` (each ``kind``,
``message``, ``since``), ``warnings`` (recent trouble with an input: each ``source``,
``message``, ``since``), ``sources`` (``video``, ``drone``, ``vessel`` and ``measurement``,
the frames measured: ``age_s``, ``rate_hz``, ``stale``, ``count``) and ``pose_refinement``.

When a source is stale (video older than 1 s, drone or vessel data older than 2 s by
default), or no frame was measured for 2 s (frames that arrive but cannot be measured, e.g.
a camera attitude that stopped while positions go on), every section is marked ``stale`` and
a ``stale_*`` alarm is raised: the distances shown are the last ones, never current.
:meth:`LiveEngine.refresh` re-evaluates that between frames, so a stopped stream raises its
alarm without a new frame. Times: ``now_s`` is the process's monotonic clock; ``time_s`` a
frame's time on the flight's clock (for the tracker).

A vessel known from AIS reports seldom (a class B transponder: every 3 min under 2 kn) is
carried from frame to frame by the poses the images placed (:mod:`harborsight.flight.pose_carry`):
while the newest measured frame's pose was carried so, and the measurements are current, the
vessel's source is not stale however old its newest report (``sources.vessel`` says
``placed_by_image``), and a frame that neither the reports nor the images place is not measured.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from harborsight.clearance.gross_errors import CONTRADICTION_ADVICE
from harborsight.clearance.measure import ClearanceSettings
from harborsight.clearance.report import STATUS_CLEAR, STATUS_OK, ClearanceReport
from harborsight.clearance.uncertainty import bounded_where_band_left, seen_lower_bound_m
from harborsight.errors import HarborsightError
from harborsight.flight.pose_carry import VesselPoseCarry, placed_by_image
from harborsight.flight.stamps import StampResolution
from harborsight.flight.tracker_inputs import Reading, TrackerSettings, seen_clear
from harborsight.flight.tracking import SectionTracker
from harborsight.frame import FrameMetadata
from harborsight.live.alarms import CAUTION, DANGER, AlarmSettings, SectionAlarm
from harborsight.live.health import SourceHealth
from harborsight.pipeline import Segmenter, VesselCache, frame_labels

SCHEMA = "harborsight.live/1"
#: the inputs, and the frames measured from them, whose age the state shows
SOURCES = ("video", "drone", "vessel", "measurement")
#: how long an input's warning stays in the state, and how many are kept
WARNING_SHOWN_S, WARNINGS_KEPT = 30.0, 8
#: a section's state, and an alarm's kind, when the image contradicts the sensors' pose
POSE_CONTRADICTED = "pose_contradicted"
logger = logging.getLogger("harborsight.live")


def _rounded(value: float | None, digits: int) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


@dataclass
class LiveEngine:
    """Measures frames as they come and keeps the state (module docstring). Thread-safe:
    :meth:`state` may be read from a web server's thread while frames are processed."""

    segmenter: Segmenter | None
    vessels: VesselCache
    clearance: ClearanceSettings = field(default_factory=ClearanceSettings)
    alarm_settings: AlarmSettings = field(default_factory=AlarmSettings)
    tracker_settings: TrackerSettings = field(default_factory=TrackerSettings)

    def __post_init__(self) -> None:
        s = self.alarm_settings
        self.health = {"video": SourceHealth("video", s.video_stale_s),
                       "drone": SourceHealth("drone", s.telemetry_stale_s),
                       "vessel": SourceHealth("vessel", s.vessel_stale_s or s.telemetry_stale_s),
                       "measurement": SourceHealth("measurement", s.measurement_stale_s)}
        #: why the newest frame that came could not be measured (None once one is)
        self._last_failure: str | None = None
        self._trackers: dict[int, SectionTracker] = {}
        self._stamps = StampResolution()     # frame times coarser than the frames
        self._alarms: dict[int, SectionAlarm] = {}
        self._report: ClearanceReport | None = None
        self._image: np.ndarray | None = None          # the measured frame, for the video
        self._sections: list[dict] = []
        self._frame_index: int | None = None
        self._frame_time: str | None = None
        self._latency_ms: float | None = None
        self._errors: list[dict] = []
        self._warnings: deque = deque(maxlen=WARNINGS_KEPT)
        self._carry = VesselPoseCarry()
        self._lock = threading.Lock()
        self._state: dict = self._build(time.monotonic())
        self.frames_measured = 0
        self.frames_failed = 0

    def warn(self, source: str, message: str, now_s: float | None = None) -> None:
        """A warning about an input (a garbled feed, a reconnection, a clock jump): in the
        state's ``warnings`` for ``WARNING_SHOWN_S`` and in the log."""
        logger.warning("%s: %s", source, message)
        with self._lock:
            self._warnings.append({"source": source, "message": message,
                                   "at_s": time.monotonic() if now_s is None else now_s})

    def source_arrived(self, name: str, now_s: float) -> None:
        """Data from ``video``, ``drone`` or ``vessel`` arrived at ``now_s``."""
        with self._lock:
            self.health[name].arrived(now_s)

    def process(self, frame_index: int, image: np.ndarray, meta: FrameMetadata, meta_path: Path,
                time_s: float | None, arrived_s: float, mask_path: Path | None = None,
                no_data: np.ndarray | None = None) -> dict:
        """Measure one frame that arrived at ``arrived_s`` (monotonic) and return the new
        state. A frame that cannot be measured leaves the sections as they were (they turn
        stale once no frame was measured for ``measurement_stale_s``) and adds a warning
        alarm; it never raises."""
        try:
            mask = frame_labels(image, mask_path, self.segmenter, meta.source or meta_path,
                                no_data, meta)
            report, disagreement = self._carry.measure(
                mask, meta, self.vessels.for_frame(meta, meta_path), self.clearance, time_s)
            if disagreement is not None:
                self.warn("vessel", disagreement)
        except HarborsightError as exc:
            return self.frame_failed(frame_index, str(exc))
        except Exception as exc:   # one bad frame must not stop the live aid
            return self.frame_failed(frame_index, f"unexpected {type(exc).__name__}: {exc}")
        with self._lock:
            stamp_note = self._update_sections(report, time_s)
            self._report, self._frame_index, self._image = report, frame_index, image
            self._frame_time = meta.timestamp
            self.frames_measured += 1
            self.health["measurement"].arrived(arrived_s)
            self._last_failure = None
            now = time.monotonic()
            self._latency_ms = 1000.0 * (now - arrived_s)
            self._state = state = self._build(now)
        if stamp_note is not None:      # once a flight: warn() takes the lock itself
            self.warn("video", stamp_note)
            with self._lock:
                self._state = state = self._build(now)
        return state

    def refresh(self, now_s: float | None = None) -> dict:
        """The state re-evaluated at ``now_s`` (ages, stale flags and alarms) without a
        new frame."""
        with self._lock:
            self._state = self._build(time.monotonic() if now_s is None else now_s)
            return self._state

    def state(self) -> dict:
        with self._lock:
            return self._state

    @property
    def frame_index(self) -> int | None:
        with self._lock:
            return self._frame_index

    def report_of(self, frame_index: int) -> ClearanceReport | None:
        """The report of the frame ``frame_index`` if it is the one measured last."""
        with self._lock:
            return self._report if self._frame_index == frame_index else None

    def annotated_jpeg(self, quality: int = 80) -> tuple[int | None, bytes | None]:
        """The newest measured frame with its sections drawn (the overlay of ``run``), as
        JPEG, and its frame index. Drawn on demand, by whoever asks (the video stream), so
        that the drawing never delays a state."""
        import cv2

        from harborsight.viz.overlay import draw_overlay

        with self._lock:
            index, image, report = self._frame_index, self._image, self._report
        if image is None or report is None:
            return None, None
        s = self.alarm_settings
        picture = draw_overlay(image, report, warn_m=s.caution_m, alarm_m=s.danger_m)
        ok, jpeg = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_QUALITY, quality])
        return index, (jpeg.tobytes() if ok else None)

    def frame_failed(self, frame_index: int, message: str) -> dict:
        """A frame that could not be measured: a ``frame_error`` alarm until the next measured
        frame; the sections stay as they were."""
        with self._lock:
            self.frames_failed += 1
            self._errors = [{"frame_index": frame_index, "message": message}]
            self._last_failure = message
            self._state = self._build(time.monotonic())
            return self._state

    def _update_sections(self, report: ClearanceReport, time_s: float | None) -> str | None:
        """The sections' tracks and alarms after this report; returns a note the first time
        two frames in a row share a time (:mod:`harborsight.flight.stamps`)."""
        self._errors = []
        sections = []
        time_sigma_s, note = 0.0, None
        if time_s is not None:
            time_sigma_s, note = self._stamps.observe(report.image, time_s)
        for section in report.sections:
            fits = (section.status == STATUS_OK and not section.truncated
                    and not report.sensors_contradicted)
            estimate = None
            if time_s is not None:
                tracker = self._trackers.setdefault(section.index, SectionTracker(self.tracker_settings))
                reading = (Reading(section.distance_m, section.sigma_m, section.sigma_random_m,
                                   section.own_rate_mps, section.own_rate_sigma_mps, time_sigma_s)
                           if fits else None)
                estimate = tracker.step(time_s, reading,
                                        None if report.sensors_contradicted else seen_clear(section))
            # a closing speed is shown only beside a current distance (the tracker coasts
            # through frames without one, but the crew should not read it as measured)
            closing = estimate.closing_speed_mps if estimate is not None and fits else None
            ttc = estimate.time_to_contact_s if estimate is not None and fits else None
            alarm = self._alarms.setdefault(section.index, SectionAlarm(self.alarm_settings))
            if report.sensors_contradicted:
                # no distance to show, publish or alarm on: the pose it was read with is known
                # wrong (the frame's own alarm says so); the section's alarm holds its level
                sections.append({"index": section.index, "measured": POSE_CONTRADICTED,
                                 "distance_m": None, "distance_lower_m": None, "sigma_m": None,
                                 "clear_to_m": None, "hidden_to_m": None, "filtered_distance_m": None,
                                 "closing_speed_mps": None, "time_to_contact_s": None})
                continue
            if section.status == STATUS_OK:
                value = section.distance_m if section.distance_lower_m is None else section.distance_lower_m
                if bounded_where_band_left(section) and section.clear_to_m < alarm.settings.caution_m:
                    # the bound is where its band left the picture, short of the caution distance:
                    # that says nothing of what lies there, and the alarm holds its level, as for
                    # a clear band seen short, unless the obstacle seen calls for more itself
                    value = seen_lower_bound_m(section)
                    value = value if value < alarm.settings.caution_m else None
                if (value is not None and value >= alarm.settings.caution_m
                        and section.hidden_to_m is not None
                        and section.hidden_to_m >= alarm.settings.danger_m):
                    # an obstacle seen past the caution distance says nothing of the water the
                    # vessel hides nearer (behind its deckhouse): it raises no alarm, nor lowers one
                    value = None
                if value is not None:
                    # a bound that is not a number says nothing: the safe side, 0 m
                    alarm.update(time.monotonic(), value if math.isfinite(value) else 0.0, ttc)
            elif section.status == STATUS_CLEAR and (
                    section.clear_to_m is None or section.clear_to_m >= alarm.settings.caution_m) and (
                    section.hidden_to_m is None or section.hidden_to_m < alarm.settings.danger_m):
                # measured: nothing solid in its band, seen past the caution distance (a band
                # that leaves the picture sooner says nothing, and the alarm holds its level;
                # so does one whose water the vessel itself hides out to the danger distance,
                # behind its deckhouse: an obstacle there would not be seen; a flared deck's
                # metre at nadir does not hold it)
                alarm.update(time.monotonic(), None, None)
            sections.append({
                "index": section.index, "measured": section.status,
                "distance_m": _rounded(section.distance_m, 3),
                "distance_lower_m": _rounded(section.distance_lower_m, 3),
                "sigma_m": _rounded(section.sigma_m, 3),
                "clear_to_m": _rounded(section.clear_to_m, 2),
                "hidden_to_m": _rounded(section.hidden_to_m, 2),
                "filtered_distance_m": _rounded(estimate.distance_m if estimate else None, 3),
                "closing_speed_mps": _rounded(closing, 3),
                "time_to_contact_s": _rounded(ttc, 1),
            })
        self._sections = sections
        return note

    def _vessel_placed_by_image(self, now_s: float) -> bool:
        """Whether the newest measured frame's vessel pose was carried by the images and its
        own image placed it again, and the measurements are current: the vessel's own
        reports may then be old."""
        report = self._report
        return bool(report is not None and (report.pose_refinement or {}).get("carried_from")
                    and placed_by_image(report.pose_refinement)
                    and not self.health["measurement"].stale(now_s))

    def _build(self, now_s: float) -> dict:
        placed_by_image = self._vessel_placed_by_image(now_s)
        stale_sources = [name for name in SOURCES if self.health[name].stale(now_s)
                         and not (name == "vessel" and placed_by_image)]
        stale = bool(stale_sources)
        sections, alarms = [], []
        for entry in self._sections:
            alarm = self._alarms.get(entry["index"])
            level = alarm.status if alarm is not None else "ok"
            status = level if entry["measured"] in (STATUS_OK, STATUS_CLEAR) else entry["measured"]
            sections.append({**{k: v for k, v in entry.items() if k != "measured"},
                             "status": status, "measured": entry["measured"], "level": level,
                             "alarm": level in (CAUTION, DANGER), "stale": stale})
            if alarm is not None and level in (CAUTION, DANGER):
                distance = entry["distance_m"]
                closing = entry["closing_speed_mps"]
                message = (f"section {entry['index']}: {level}, "
                           + ("distance unknown" if distance is None else f"{distance:.1f} m")
                           + ("" if closing is None else f", closing at {closing:.2f} m/s"))
                alarms.append({"kind": level, "section": entry["index"], "message": message,
                               "since": _wall_iso(now_s, alarm.since)})
        for name in stale_sources:
            since = self.health[name].stale_since(now_s)
            age = self.health[name].age_s(now_s)
            if name == "measurement":
                why = f" (the newest frame: {self._last_failure})" if self._last_failure else ""
                message = ("no frame measured yet" if age is None else
                           f"no frame measured for {age:.1f} s: distances are not current") + why
            else:
                message = (f"no {name} data yet" if age is None else
                           f"{name} data is {age:.1f} s old: distances are not current")
            alarms.append({"kind": f"stale_{name}", "message": message,
                           "since": _wall_iso(now_s, since)})
        for error in self._errors:
            alarms.append({"kind": "frame_error", "message": error["message"],
                           "since": _wall_iso(now_s, now_s)})
        if self._report is not None and self._report.sensors_contradicted:
            reason = (self._report.pose_refinement or {}).get("reason") or ""
            alarms.append({"kind": POSE_CONTRADICTED, "message": (
                f"the image contradicts the sensors' pose ({reason}): no distance is shown; "
                f"{CONTRADICTION_ADVICE}"),
                "since": _wall_iso(now_s, now_s)})
        warnings = [{"source": w["source"], "message": w["message"],
                     "since": _wall_iso(now_s, w["at_s"])}
                    for w in self._warnings if now_s - w["at_s"] <= WARNING_SHOWN_S]
        report = self._report
        distances = [s["distance_m"] for s in sections if s["distance_m"] is not None]
        sources = {name: self.health[name].to_dict(now_s) for name in SOURCES}
        if placed_by_image:
            sources["vessel"].update(stale=False, placed_by_image=True)
        return {
            "schema": SCHEMA,
            "time": datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z"),
            "frame_index": self._frame_index,
            "frame_time": self._frame_time,
            "latency_ms": _rounded(self._latency_ms, 1),
            "vessel": report.vessel if report is not None else None,
            "min_distance_m": min(distances) if distances else None,
            "stale": stale,
            "sections": sections,
            "alarms": alarms,
            "warnings": warnings,
            "sources": sources,
            "pose_refinement": report.pose_refinement if report is not None else None,
        }


def _wall_iso(now_s: float, at_s: float | None) -> str | None:
    """A monotonic time as UTC wall time (through the offset between the two clocks now)."""
    if at_s is None:
        return None
    wall = time.time() - (now_s - at_s)
    return datetime.fromtimestamp(wall, UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")
