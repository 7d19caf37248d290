"""A whole flight: segment, measure and annotate every frame; write the run's outputs.

Outputs in ``out_dir``:

* ``reports/<stem>.json``: ``harborsight.report/1`` per measured frame;
* ``overlays/<stem>.png``: the annotated frame (optional);
* ``annotated.mp4``: every frame in flight order, measured ones annotated, skipped ones
  with a red band naming the reason (optional);
* ``sections.csv``: one row per section per measured frame, with closing speed and time to
  contact (:mod:`harborsight.flight.timeline`), written as the run goes;
* ``timeline.png``: clearance of every section over time;
* ``run.json``: inputs, settings, counts, timing, every skipped frame with its reason, and
  ``completed`` (false, with ``aborted``, when the run was stopped or failed part-way:
  ``KeyboardInterrupt`` for Ctrl-C). A frame is counted as measured once its report is on
  disk, so that the counts of an interrupted run are those of the reports it wrote.

Time of a frame (``time_s``), on one clock for the whole run (:class:`FlightClock`): the
frames' ``timestamp``, in seconds since the first timestamped frame, if the first frame that
has a time at all has a timestamp; else the position in the video (seconds since the video's
start). Frames of a folder before its first timestamp have no time. A frame whose time is
missing, unreadable or out of order is still measured; it is left out of the closing speeds
and listed under ``warnings`` in ``run.json``.

A run into a folder that holds an earlier run's outputs first removes them (the files named
above: reports/*.json, overlays/*.png and the run's own files), so that what is there
afterwards is this run's alone.

Outputs are written per frame: a frame whose report cannot be written is skipped like a bad
input (nothing of it in ``sections.csv``); an overlay or video that cannot be written is a
warning, and the run goes on.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from harborsight.clearance.measure import ClearanceSettings
from harborsight.clearance.refinement_summary import refinement_counts
from harborsight.errors import HarborsightError, InputError
from harborsight.files import strict_json, write_image, write_text_atomic
from harborsight.flight.pose_carry import VesselPoseCarry
from harborsight.flight.sources import NO_METADATA, FlightFrame
from harborsight.flight.timeline import ClearanceTimeline, SectionTrend, timestamp_seconds, write_rows
from harborsight.flight.tracker_inputs import MEASURED_STATES
from harborsight.pipeline import Segmenter, VesselCache, frame_labels
from harborsight.viz.overlay import GREY, RED, draw_banner, draw_overlay

RUN_SCHEMA = "harborsight.run/1"
DEFAULT_VIDEO_FPS = 5.0


@dataclass
class RunOptions:
    settings: ClearanceSettings = field(default_factory=ClearanceSettings)
    overlays: bool = True
    video: bool = True
    video_fps: float | None = None       # None: the source video's, else from timestamps
    window_s: float = 2.0                # closing-speed fit window
    warn_m: float = 5.0
    alarm_m: float = 2.0


@dataclass
class RunSummary:
    frames: int = 0
    measured: int = 0
    without_metadata: int = 0
    skipped: list[dict] = field(default_factory=list)     # {"frame", "source", "error"}
    warnings: list[dict] = field(default_factory=list)    # {"frame", "source", "warning"}
    min_distance_m: float | None = None
    min_distance_frame: int | None = None
    seconds: float = 0.0
    outputs: dict[str, str] = field(default_factory=dict)
    completed: bool = False
    aborted: str | None = None        # why the run stopped early
    pose_refinements: list[dict] = field(default_factory=list)   # per measured frame

    def to_dict(self) -> dict:
        return {
            "completed": self.completed, "aborted": self.aborted,
            "frames": self.frames, "measured": self.measured,
            "skipped": len(self.skipped), "without_metadata": self.without_metadata,
            "min_distance_m": self.min_distance_m, "min_distance_frame": self.min_distance_frame,
            "seconds": round(self.seconds, 2),
            "frames_per_second": round(self.frames / self.seconds, 2) if self.seconds else None,
            "outputs": self.outputs, "skipped_frames": self.skipped,
            "warnings": self.warnings,
            "pose_refinement": refinement_counts(self.pose_refinements),
        }


class _VideoWriter:
    """mp4 (MPEG-4 part 2, which every OpenCV build writes) opened at the first frame; later
    frames of another size are resized to the first one's."""

    def __init__(self, path: Path, fps: float, size: tuple[int, int] | None = None) -> None:
        self.path, self.fps = path, fps
        self.writer: cv2.VideoWriter | None = None
        #: (width, height): the first frame's, or the source's where it says (a video)
        self.size: tuple[int, int] | None = size
        self.frames = 0

    def write(self, image: np.ndarray) -> None:
        if self.writer is None:
            self.size = self.size or (image.shape[1], image.shape[0])
            self.writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"),
                                          self.fps, self.size)
            if not self.writer.isOpened():
                raise HarborsightError(f"{self.path}: OpenCV cannot write mp4 video here")
        if (image.shape[1], image.shape[0]) != self.size:
            image = cv2.resize(image, self.size, interpolation=cv2.INTER_AREA)
        self.writer.write(image)
        self.frames += 1

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()


#: a frame's timestamp and its position in the video may drift apart this much before
#: the run says so (seconds; a constant offset between the clocks is fine)
DRIFT_SAID_S = 0.25


class FlightClock:
    """One time base for a run, fixed by the first frame that has a time: ``timestamp`` when
    that frame has one (a later frame without one raises: mixing clocks would corrupt the
    closing-speed fits, so the runner measures it untimed, as it does a frame whose timestamp
    cannot be read), else the video position. Until then every time is None.

    Timestamps count from the first timestamped frame; video positions from the video's
    start, so that ``time_s`` of a video run is the time in the video.

    Where frames have both, the two must keep step: a constant offset is a clock's, but
    a drift of more than :data:`DRIFT_SAID_S` means metadata lines paired with the wrong
    frames (lines written at the telemetry's rate without ``frame_index``, a video with
    dropped frames): :attr:`drift_warning` says so, once."""

    def __init__(self) -> None:
        self.base: str | None = None        # "timestamp" or "video"; None until a frame has one
        self.start_s: float | None = None
        self._pair_start: tuple[float, float] | None = None   # (timestamp, video time)
        #: set once, when a frame's timestamp and video position drift apart (for run.json)
        self.drift_warning: str | None = None
        self._drift_said = False

    def _check_drift(self, frame: FlightFrame, stamp: float) -> None:
        if frame.video_time_s is None or self._drift_said:
            return
        if self._pair_start is None:
            self._pair_start = (stamp, frame.video_time_s)
            return
        drift = (stamp - self._pair_start[0]) - (frame.video_time_s - self._pair_start[1])
        if abs(drift) > DRIFT_SAID_S:
            self._drift_said = True
            self.drift_warning = (
                f"timestamp: {stamp - self._pair_start[0]:.2f} s after the first timed frame, "
                f"but {frame.video_time_s - self._pair_start[1]:.2f} s later in the video: the "
                "metadata lines and the video frames drift apart (lines at the telemetry's "
                "rate paired one to one with frames? give each line its frame_index); the "
                "timestamps are used")

    def seconds(self, frame: FlightFrame) -> float | None:
        stamp = timestamp_seconds(frame.meta)
        if stamp is not None:
            self._check_drift(frame, stamp)
        if self.base is None:
            if stamp is not None:
                self.base, self.start_s = "timestamp", stamp
            elif frame.video_time_s is not None:
                self.base, self.start_s = "video", 0.0
            else:
                return None
        if self.base == "timestamp":
            if stamp is None:
                raise InputError(frame.source, "timestamp", "missing, while this run's frames "
                                 "are timed by their timestamps (set by its first timed frame)")
            return stamp - self.start_s
        return None if frame.video_time_s is None else frame.video_time_s - self.start_s


def trend_footer(trends: dict[int, SectionTrend], has_time: bool) -> str:
    """One line on the closing section nearest to contact (or why there is none)."""
    if not has_time:
        return "closing speed: frames need timestamps"
    # only sections measured this frame: a coasting track's prediction is no reading
    closing = [(t.time_to_contact_s, k, t.closing_speed_mps) for k, t in trends.items()
               if t.time_to_contact_s is not None and t.estimate.state in MEASURED_STATES]
    if closing:
        ttc, k, speed = min(closing)
        when = f"{ttc:.1f}" if ttc < 10 else f"{ttc:.0f}"
        return f"section {k} closing at {speed:.2f} m/s, contact in {when} s"
    speeds = [t.closing_speed_mps for t in trends.values() if t.closing_speed_mps is not None]
    return "no section closing" if speeds else "closing speed: collecting frames"


def run_flight(
    frames: Iterable[FlightFrame], out_dir: Path, vessels: VesselCache,
    segmenter: Segmenter | None, options: RunOptions | None = None, *,
    source_fps: float | None = None, inputs: dict | None = None,
    on_frame: Callable[[FlightFrame], None] | None = None,
    source_warnings: Iterable[str] = (), frame_size: tuple[int, int] | None = None,
) -> RunSummary:
    """Measure every frame of a flight (module docstring). A frame with bad input, or one
    the measurement refuses, is recorded in the summary and skipped; the run goes on. A frame
    whose time is missing or out of order is measured, left out of the closing speeds and
    listed in ``warnings``, as are ``source_warnings`` (about the input as a whole).
    ``frame_size`` (width, height), where the source says it (a video), sizes the annotated
    video before its first picture (frames without one before it keep their places).
    ``run.json`` and the video are written however the run ends."""
    options = options or RunOptions()
    out_dir.mkdir(parents=True, exist_ok=True)
    reports_dir, overlays_dir = out_dir / "reports", out_dir / "overlays"
    _remove_earlier_outputs(out_dir)
    reports_dir.mkdir(exist_ok=True)
    if options.overlays:
        overlays_dir.mkdir(exist_ok=True)
    summary = RunSummary()
    summary.warnings.extend({"frame": None, "source": "input", "warning": warning}
                            for warning in source_warnings)
    timeline = ClearanceTimeline(window_s=options.window_s)
    fps = options.video_fps or source_fps or DEFAULT_VIDEO_FPS
    video = _VideoWriter(out_dir / "annotated.mp4", fps, frame_size) if options.video else None
    clock = FlightClock()
    carry = VesselPoseCarry()
    stems = _OutputStems()
    started = time.perf_counter()
    csv_path = out_dir / "sections.csv"
    try:
        with csv_path.open("w", newline="") as csv_handle:
            csv_out = ClearanceTimeline.csv_writer(csv_handle)
            for frame in frames:
                annotated = None
                if frame.error is None:
                    annotated = _measure_one(frame, summary, timeline, clock, carry, stems,
                                             csv_out, csv_handle, reports_dir, overlays_dir,
                                             segmenter, vessels, options)
                if frame.error is not None:
                    if frame.error == NO_METADATA:
                        summary.without_metadata += 1
                    else:
                        summary.skipped.append({"frame": frame.index, "source": frame.source,
                                                "error": frame.error})
                    summary.frames += frame.is_frame
                    if frame.image is not None:
                        annotated = frame.image.copy()
                        if frame.error == NO_METADATA:
                            draw_banner(annotated, "not measured: no metadata for this frame",
                                        GREY)
                        else:
                            draw_banner(annotated, f"skipped: {_short(frame.error)}", RED)
                    elif frame.is_frame and video is not None and video.size is not None:
                        # a frame whose picture could not be read keeps its place in the video
                        annotated = np.full((video.size[1], video.size[0], 3), 40, np.uint8)
                        draw_banner(annotated, f"skipped: {_short(frame.error)}", RED)
                if video is not None and annotated is not None:
                    try:
                        video.write(annotated)
                    except HarborsightError as exc:     # the measurements stand without it
                        summary.warnings.append({"frame": frame.index, "source": str(video.path),
                                                 "warning": f"{exc}; no annotated video"})
                        video.close()
                        video.path.unlink(missing_ok=True)
                        video = None
                if on_frame is not None:
                    on_frame(frame)
        summary.completed = True
    except BaseException as exc:
        summary.aborted = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        raise
    finally:
        close = getattr(frames, "close", None)      # a generator: release its files now
        if close is not None:
            close()
        if video is not None:
            video.close()
        summary.seconds = time.perf_counter() - started
        _write_run_record(out_dir, summary, timeline, options, segmenter, inputs,
                          fps if video is not None else None, video)
    return summary


def _remove_earlier_outputs(out_dir: Path) -> None:
    """Delete what an earlier run wrote here (module docstring); nothing else is touched."""
    stale = [out_dir / name for name in ("annotated.mp4", "timeline.png", "sections.csv",
                                         "run.json")]
    stale += sorted((out_dir / "reports").glob("*.json")) + sorted(
        (out_dir / "overlays").glob("*.png"))
    for path in stale:
        if path.is_file():
            path.unlink()


def _measure_one(frame: FlightFrame, summary: RunSummary, timeline: ClearanceTimeline,
                 clock: FlightClock, carry: VesselPoseCarry, stems: _OutputStems, csv_out,
                 csv_handle, reports_dir: Path, overlays_dir: Path, segmenter: Segmenter | None,
                 vessels: VesselCache, options: RunOptions) -> np.ndarray | None:
    """Measure one frame and write its outputs; sets ``frame.error`` when it cannot be
    measured. A dead-reckoned vessel pose is replaced by the one the frames before placed
    in their images, where that is better (:mod:`harborsight.flight.pose_carry`). Returns
    the annotated picture for the video."""
    warnings = []
    try:
        if frame.time_error is not None:   # a bad time costs the closing speeds, not the frame
            time_s = None
            warnings.append(f"{frame.time_error}: measured, but left out of the closing speeds")
        else:
            try:
                time_s = clock.seconds(frame)
            except InputError as exc:
                time_s = None
                warnings.append(f"{exc}: measured, but left out of the closing speeds")
            if clock.drift_warning is not None:
                warnings.append(f"{frame.source}: {clock.drift_warning}")
                clock.drift_warning = None
        mask = frame_labels(frame.image, frame.mask_path, segmenter, frame.source, frame.no_data,
                            frame.meta)
        report, disagreement = carry.measure(mask, frame.meta,
                                             vessels.for_frame(frame.meta, frame.meta_path),
                                             options.settings, time_s)
        if disagreement is not None:
            warnings.append(f"{frame.source}: {disagreement}")
    except HarborsightError as exc:
        frame.error = str(exc)
        return None
    except Exception as exc:  # one bad frame must not end the run
        frame.error = f"{frame.source}: unexpected {type(exc).__name__}: {exc}"
        return None
    stem = stems.claim(frame)
    try:        # the report first: a frame without one leaves no trace in the CSV or the fits
        report.write(reports_dir / f"{stem}.json")
    except (OSError, ValueError) as exc:
        frame.error = (f"{frame.source}: image: its report {stem!r}.json cannot be written "
                       f"({type(exc).__name__}: {exc})")
        return None
    # counted as soon as its report is on disk: a run interrupted from here on still
    # records exactly the reports it wrote
    summary.measured += 1
    summary.pose_refinements.append(report.pose_refinement or {})
    summary.frames += 1
    trends, rows, order_warning = timeline.add(frame.index, time_s, report)
    if order_warning:
        warnings.append(f"{frame.source}: timestamp: {order_warning}")
    write_rows(csv_out, rows)
    csv_handle.flush()
    try:
        annotated = draw_overlay(frame.image, report, warn_m=options.warn_m,
                                 alarm_m=options.alarm_m,
                                 footer=trend_footer(trends, time_s is not None))
    except Exception as exc:  # the measurement stands without its picture
        warnings.append(f"{frame.source}: overlay not drawn ({type(exc).__name__}: {exc})")
        annotated = frame.image.copy()
        draw_banner(annotated, "measured; overlay could not be drawn", GREY)
    if options.overlays:
        overlay_path = overlays_dir / f"{stem}.png"
        if not write_image(overlay_path, annotated):
            warnings.append(f"{frame.source}: overlay {overlay_path} could not be written")
    summary.warnings.extend({"frame": frame.index, "source": frame.source, "warning": w}
                            for w in warnings)
    md = report.min_distance_m
    if md is not None and (summary.min_distance_m is None or md < summary.min_distance_m):
        summary.min_distance_m, summary.min_distance_frame = md, frame.index
    return annotated


class _OutputStems:
    """File stems of the frames' reports and overlays: the frame's ``image`` stem, with the
    frame index added when an earlier frame of the run already used it (several frames may
    name one image, e.g. every line of a video's metadata naming the video)."""

    def __init__(self) -> None:
        self.used: set[str] = set()

    def claim(self, frame: FlightFrame) -> str:
        stem, base, repeat = frame.stem, frame.stem, 0
        if stem in self.used:
            stem = f"{base}-{frame.index:06d}"
        while stem in self.used:
            repeat += 1
            stem = f"{base}-{frame.index:06d}-{repeat}"
        self.used.add(stem)
        return stem


def _write_run_record(out_dir: Path, summary: RunSummary, timeline: ClearanceTimeline,
                      options: RunOptions, segmenter: Segmenter | None, inputs: dict | None,
                      video_fps: float | None, video: _VideoWriter | None) -> None:
    reports_dir, overlays_dir = out_dir / "reports", out_dir / "overlays"
    summary.outputs = {"reports": str(reports_dir), "sections_csv": str(out_dir / "sections.csv")}
    if options.overlays:
        summary.outputs["overlays"] = str(overlays_dir)
    if video is not None and video.frames:
        summary.outputs["video"] = str(video.path)
    try:
        if timeline.plot(out_dir / "timeline.png", alarm_m=options.alarm_m,
                         warn_m=options.warn_m):
            summary.outputs["timeline"] = str(out_dir / "timeline.png")
    except Exception as exc:  # run.json matters more than the plot
        summary.warnings.append({"frame": None, "source": str(out_dir / "timeline.png"),
                                 "warning": f"timeline not plotted ({type(exc).__name__}: "
                                            f"{exc})"})
    record = {"schema": RUN_SCHEMA, "inputs": inputs or {},
              "settings": {"method": options.settings.method,
                           "pose_margin_px": options.settings.pose_margin_px,
                           "own_rim_px": options.settings.own_rim_px,
                           "n_sections": options.settings.n_sections,
                           "section_length_m": options.settings.section_length_m,
                           "closing_window_s": options.window_s,
                           "sigma_options": dict(options.settings.sigma_options),
                           "own_motion": options.settings.own_motion,
                           "video_fps": video_fps,
                           "model": str(segmenter.path) if segmenter is not None else None,
                           "flips": getattr(segmenter, "flips", 1),
                           "segment_gsd_m": getattr(segmenter, "target_gsd_m", None)},
              **summary.to_dict()}
    write_text_atomic(out_dir / "run.json",
                      strict_json(record, indent=2, default=str) + "\n")


def _short(text: str, limit: int = 90) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."
