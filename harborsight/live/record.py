"""``live --record DIR``: what the live aid saw and said, and what ``run`` writes, written as
it goes.

* ``states.jsonl``: every published ``harborsight.live/1`` state, one per line, flushed;
* ``images/NNNNNN.jpg`` and ``frames/NNNNNN.json``: each measured frame and its metadata (a
  ``harborsight.frame/1`` file naming the image, ``vessel_spec`` made absolute), so the
  folder is a flight that ``harborsight run DIR`` replays frame by frame;
* ``reports/NNNNNN.json``: the frame's ``harborsight.report/1``, as measured live;
* ``sections.csv``: one row per section per measured frame, ``run``'s columns and filter
  (:class:`~harborsight.flight.timeline.ClearanceTimeline`), flushed after each frame;
* ``annotated.mp4``: the measured frames with their sections drawn (``run``'s overlay), H.264
  in fragmented MP4: a fragment per second, so a killed process leaves a video that plays
  up to its last fragment;
* ``run.json``: ``harborsight.run/1`` of the session (counts, closest approach, outputs),
  rewritten every few seconds and at the end, ``completed`` false until then;
* ``timeline.png``: the sections' clearance over time, at the end.

The frame's files are written by a thread of the recorder's own, so that drawing and encoding
never delay a state: the live loop hands over the frame, its report and its time. Should the
writer fall behind by more than :data:`VIDEO_BACKLOG` frames, frames are left out of the
video (counted in ``run.json``); the images, metadata, reports and CSV rows never are. Every
file is whole when written (images, frames and reports atomically, the frame's JSON after its
image), so a killed process leaves a readable record of everything up to its last frame.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from harborsight.clearance.report import ClearanceReport
from harborsight.files import strict_json, write_bytes_atomic, write_text_atomic
from harborsight.flight.runner import RUN_SCHEMA
from harborsight.flight.timeline import ClearanceTimeline, write_rows
from harborsight.frame import FrameMetadata

#: JPEG quality of the recorded frames
JPEG_QUALITY = 92
#: frames waiting for the writer beyond which the video leaves frames out
VIDEO_BACKLOG = 8
#: how often run.json is rewritten while the session runs
RUN_RECORD_EVERY_S = 5.0


@dataclass
class _Measured:
    index: int                  # the frame's index in the session
    image: np.ndarray
    meta: FrameMetadata
    meta_path: Path | None
    report: ClearanceReport | None
    time_s: float | None


class _FragmentedVideo:
    """H.264 in fragmented MP4 (PyAV), opened at the first frame; later frames of another
    size are resized to it. Timestamps in milliseconds of the session's clock."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.container = None
        self.stream = None
        self.size: tuple[int, int] | None = None
        self.frames = 0
        self._last_pts = -1

    def write(self, picture: np.ndarray, t_s: float) -> None:
        import av

        if self.container is None:
            height, width = picture.shape[:2]
            self.size = (width - width % 2, height - height % 2)     # yuv420p: even sizes
            self.container = av.open(str(self.path), mode="w", format="mp4", options={
                "movflags": "frag_keyframe+empty_moov+default_base_moof"})
            self.stream = self.container.add_stream("libx264", rate=10)
            self.stream.width, self.stream.height = self.size
            self.stream.pix_fmt = "yuv420p"
            self.stream.time_base = Fraction(1, 1000)
            self.stream.codec_context.time_base = Fraction(1, 1000)
            self.stream.options = {"preset": "ultrafast", "g": "10"}
        if (picture.shape[1], picture.shape[0]) != self.size:
            picture = cv2.resize(picture, self.size, interpolation=cv2.INTER_AREA)
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(picture), format="bgr24")
        frame.pts = max(round(t_s * 1000.0), self._last_pts + 1)
        self._last_pts = frame.pts
        frame.time_base = Fraction(1, 1000)
        for packet in self.stream.encode(frame):
            self.container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        if self.container is not None:
            for packet in self.stream.encode(None):
                self.container.mux(packet)
            self.container.close()
            self.container = None


class SessionRecorder:
    """The record of one live session (module docstring)."""

    def __init__(self, folder: Path, *, inputs: dict | None = None, settings: dict | None = None,
                 caution_m: float = 5.0, danger_m: float = 2.0) -> None:
        self.folder = Path(folder)
        for name in ("images", "frames", "reports"):
            (self.folder / name).mkdir(parents=True, exist_ok=True)
        self._states = (self.folder / "states.jsonl").open("w", encoding="utf-8")
        self._csv = (self.folder / "sections.csv").open("w", newline="", encoding="utf-8")
        self._csv_out = ClearanceTimeline.csv_writer(self._csv)
        self.timeline = ClearanceTimeline()
        self.video = _FragmentedVideo(self.folder / "annotated.mp4")
        self.inputs, self.settings = inputs or {}, settings or {}
        self.caution_m, self.danger_m = caution_m, danger_m
        self.frames = 0                  # frames handed over
        self.written = 0                 # frames whose files are all written
        self.video_skipped = 0
        self.min_distance: tuple[float, int] | None = None
        self.warnings: list[dict] = []
        self._queue: queue.Queue = queue.Queue()
        self._started = time.monotonic()
        self._last_record_s = 0.0
        self._completed = False
        self._thread = threading.Thread(target=self._write_loop, name="harborsight-live-record",
                                        daemon=True)
        self._thread.start()
        self._write_run_record()

    def state(self, state: dict) -> None:
        self._states.write(json.dumps(state) + "\n")
        self._states.flush()

    def frame(self, image: np.ndarray, meta: FrameMetadata, meta_path: Path | None,
              report: ClearanceReport | None = None, time_s: float | None = None) -> None:
        """Hand over a measured frame (its files are written by the recorder's thread)."""
        self._queue.put(_Measured(self.frames, image, meta, meta_path, report, time_s))
        self.frames += 1

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self._write(item, backlog=self._queue.qsize())
            except Exception as exc:      # a full disk, a codec error: note it, keep going
                self.warnings.append({"frame": item.index, "source": str(self.folder),
                                      "warning": f"{type(exc).__name__}: {exc}"})
            if time.monotonic() - self._last_record_s >= RUN_RECORD_EVERY_S:
                self._write_run_record()

    def _write(self, item: _Measured, backlog: int) -> None:
        from harborsight.viz.overlay import draw_overlay

        stem = f"{item.index:06d}"
        ok, jpeg = cv2.imencode(".jpg", item.image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise ValueError("the frame could not be encoded as JPEG")
        write_bytes_atomic(self.folder / "images" / f"{stem}.jpg", jpeg.tobytes())
        record = item.meta.to_dict()
        record["image"] = f"{stem}.jpg"
        spec = record.get("vessel_spec")
        if isinstance(spec, str) and item.meta_path is not None and not Path(spec).is_absolute():
            record["vessel_spec"] = str((Path(item.meta_path).parent / spec).resolve())
        write_text_atomic(self.folder / "frames" / f"{stem}.json", json.dumps(record, indent=1) + "\n")
        if item.report is not None:
            item.report.image = f"{stem}.jpg"
            item.report.write(self.folder / "reports" / f"{stem}.json")
            _, rows, _ = self.timeline.add(item.index, item.time_s, item.report)
            write_rows(self._csv_out, rows)
            self._csv.flush()
            distance = item.report.min_distance_m
            if distance is not None and (self.min_distance is None or distance < self.min_distance[0]):
                self.min_distance = (distance, item.index)
            if backlog > VIDEO_BACKLOG:
                self.video_skipped += 1
            else:
                picture = draw_overlay(item.image, item.report, warn_m=self.caution_m,
                                       alarm_m=self.danger_m)
                self.video.write(picture, time.monotonic() - self._started)
        self.written += 1

    def _write_run_record(self) -> None:
        self._last_record_s = time.monotonic()
        outputs = {"images": str(self.folder / "images"), "frames": str(self.folder / "frames"),
                   "reports": str(self.folder / "reports"),
                   "sections_csv": str(self.folder / "sections.csv"),
                   "states": str(self.folder / "states.jsonl")}
        if self.video.frames:
            outputs["video"] = str(self.video.path)
        if (self.folder / "timeline.png").is_file():
            outputs["timeline"] = str(self.folder / "timeline.png")
        record = {
            "schema": RUN_SCHEMA, "source": "live", "inputs": self.inputs,
            "settings": self.settings, "completed": self._completed,
            "frames": self.written, "measured": self.written,
            "min_distance_m": None if self.min_distance is None else round(self.min_distance[0], 3),
            "min_distance_frame": None if self.min_distance is None else self.min_distance[1],
            "seconds": round(time.monotonic() - self._started, 2),
            "video_frames": self.video.frames, "video_frames_left_out": self.video_skipped,
            "outputs": outputs, "warnings": self.warnings,
        }
        write_text_atomic(self.folder / "run.json", strict_json(record, indent=2, default=str) + "\n")

    def close(self) -> None:
        """Write what is waiting, close the files, plot the timeline and mark the record
        complete."""
        self._queue.put(None)
        self._thread.join()
        self._states.close()
        self._csv.close()
        try:
            self.video.close()
        except Exception as exc:
            self.warnings.append({"frame": None, "source": str(self.video.path),
                                  "warning": f"video not closed ({type(exc).__name__}: {exc})"})
        try:
            self.timeline.plot(self.folder / "timeline.png", alarm_m=self.danger_m,
                               warn_m=self.caution_m)
        except Exception as exc:   # run.json matters more than the plot
            self.warnings.append({"frame": None, "source": str(self.folder / "timeline.png"),
                                  "warning": f"timeline not plotted ({type(exc).__name__}: {exc})"})
        self._completed = True
        self._write_run_record()
