"""Where a flight's frames come from: a folder of frames, or a video with JSON-lines metadata.

Both sources yield :class:`FlightFrame` objects in flight order. A frame whose inputs are bad
carries the reason in ``error`` instead of raising, so that the run reports it, skips its
measurement and goes on; its picture still goes into the annotated video (a dark frame with
the reason where none could be read), so the video keeps the flight's timing.

Video metadata (``--metadata flight.jsonl``): one ``harborsight.frame/1`` object per line.
A line's ``frame_index`` key (0-based) names its video frame; without that key, the n-th
non-blank line belongs to the n-th frame. ``image`` may be omitted (it names the outputs;
the default is ``<video stem>-<index>.png``). Video frames without a metadata line are
written to the annotated video unmeasured and counted, not reported as errors: telemetry is
often slower than the camera.

A video frame's position in the video is its presentation time (from the first frame's),
not its index over the container's mean rate: a variable-frame-rate video (phones, drones
in low light) or one with dropped frames has frames far from ``n / fps``. Frames are decoded
by PyAV as stored (:mod:`harborsight.flight.video_decode`): the camera's pixels, which the
metadata describes, whatever display rotation the container asks for; a frame decoded from
damaged data is reported and not measured, and the frames after it keep their numbers
(OpenCV's reader stopped at the first damaged packet). :func:`open_video` (OpenCV, its
auto-rotation off) still reads the container's rate, size and rotation.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError
from harborsight.flight.timeline import iso_seconds, timestamp_seconds
from harborsight.flight.video_decode import (
    damage_detection_note,
    read_video_frames,
    video_packet_times,
)
from harborsight.frame import (
    FrameMetadata,
    parse_frame_metadata_untimed_on_error,
    read_frame_json,
)
from harborsight.geometry.camera import CameraIntrinsics, brief
from harborsight.images import read_image_and_no_data
from harborsight.pipeline import (
    check_image_size,
    discover_jobs,
    find_frame_image,
    frame_image_path,
)
from harborsight.text_formats import parse_json_text

NO_METADATA = "no metadata"
#: the highest ``frame_index`` a metadata line may name (a year of video at 30 fps)
MAX_FRAME_INDEX = 999_999_999


@dataclass
class FlightFrame:
    """One frame of a flight: its inputs, or why they are unusable."""

    index: int                         # position in the flight (video frame index)
    source: str                        # names the frame in messages: a path, or video + index
    meta: FrameMetadata | None = None
    image: np.ndarray | None = None    # BGR
    no_data: np.ndarray | None = None  # bool (H, W): pixels without a picture (alpha 0)
    mask_path: Path | None = None      # None: segment with the model
    meta_path: Path | None = None      # the file vessel_spec paths are relative to
    video_time_s: float | None = None  # position in the video, when the source is one
    error: str | None = None
    time_error: str | None = None      # an unreadable timestamp: measured, but untimed
    is_frame: bool = True              # False: a metadata line with no picture (reported only)

    @property
    def stem(self) -> str:
        return Path(self.meta.image).stem if self.meta is not None else f"{self.index:06d}"


class FolderSource:
    """Frames of a folder (the layouts of :func:`harborsight.pipeline.discover_jobs`), in the
    natural order of their file names (frame_2 before frame_10). With ``use_masks`` a
    frame's mask (``labels/``, ``masks/`` or ``masks_dir``) is used; otherwise every frame is
    segmented."""

    def __init__(self, folder: Path, masks_dir: Path | None = None, use_masks: bool = True,
                 camera: CameraIntrinsics | None = None) -> None:
        if not folder.is_dir():
            raise InputError(folder, None, "folder not found")
        self.folder, self.camera = folder, camera
        self.jobs = discover_jobs(folder, masks_dir if use_masks else None,
                                  segment=not use_masks)
        self.frame_count = len(self.jobs)
        self.fps = fps_from_timestamps(_raw_timestamp_s(job.meta_path) for job in self.jobs)

    def frames(self) -> Iterator[FlightFrame]:
        for index, job in enumerate(self.jobs):
            frame = FlightFrame(index, str(job.meta_path), mask_path=job.mask_path,
                                meta_path=job.meta_path)
            try:
                frame.meta, frame.time_error = parse_frame_metadata_untimed_on_error(
                    read_frame_json(job.meta_path), job.meta_path, camera=self.camera,
                    base_dir=job.meta_path.parent)
                image_path = frame_image_path(job, frame.meta)
                frame.image, frame.no_data = read_image_and_no_data(image_path, camera_pixels=True)
                check_image_size(frame.image, frame.meta, image_path)
            except Exception as exc:  # one bad frame must not end the run
                frame.error = (str(exc) if isinstance(exc, InputError)
                               else f"{job.meta_path}: unexpected {type(exc).__name__}: {exc}")
                if frame.image is None:
                    frame.image = _picture_for_video(job)
            yield frame


def _picture_for_video(job) -> np.ndarray | None:
    """The picture of a frame that cannot be measured, for the annotated video: the image
    named like its JSON, else the one its (possibly otherwise broken) JSON's ``image`` key
    names; None if neither can be read."""
    path = job.image_path
    if path is None:
        try:
            data = read_frame_json(job.meta_path)
        except InputError:
            data = None
        name = data.get("image") if isinstance(data, dict) else None
        path = find_frame_image(job.meta_path, name if isinstance(name, str) else None)
    if path is None:
        return None
    try:
        return cv2.imread(str(path), cv2.IMREAD_COLOR)
    except cv2.error:
        return None


def _raw_timestamp_s(meta_path: Path) -> float | None:
    """The frame file's timestamp in seconds, or None if it has none or cannot be read (the
    frame's own reading reports that)."""
    try:
        data = read_frame_json(meta_path)
    except InputError:
        return None
    if not isinstance(data, dict):
        return None
    try:
        return iso_seconds(data.get("timestamp"))
    except (ValueError, OverflowError):
        return None


def fps_from_timestamps(times_s: Iterable[float | None]) -> float | None:
    """1 / median spacing of the known times (None with fewer than two distinct ones)."""
    known = sorted(t for t in times_s if t is not None)
    steps = [b - a for a, b in itertools.pairwise(known) if b > a]
    if not steps:
        return None
    return min(max(1.0 / statistics.median(steps), 0.1), 120.0)


def read_metadata_lines(path: Path, video_stem: str, camera: CameraIntrinsics | None = None
                        ) -> tuple[dict[int, FrameMetadata | str], list[str], dict[int, int],
                                   dict[int, str]]:
    """Parse a JSON-lines metadata file: ``{video frame index: metadata or error}``, the
    errors of lines that name no frame (a broken line when indices are explicit),
    ``{video frame index: line number}`` and ``{video frame index: timestamp error}`` of
    lines whose only fault is an unreadable timestamp (parsed without it)."""
    if path.is_dir():
        raise InputError(path, None, "is a folder, not a file (expected a JSON-lines file)")
    if not path.is_file():
        raise InputError(path, None, "metadata file not found")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    # split the bytes, not the text: a line that is not UTF-8 is that line's fault only
    lines = [(n, line) for n, line in enumerate(raw.splitlines(), 1) if line.strip()]
    if not lines:
        raise InputError(path, None, "no metadata lines")
    explicit = any(b'"frame_index"' in line for _, line in lines)
    by_frame: dict[int, FrameMetadata | str] = {}
    orphans: list[str] = []
    line_of: dict[int, int] = {}
    time_errors: dict[int, str] = {}
    for order, (line_no, line) in enumerate(lines):
        where = f"{path}:{line_no}"
        try:
            try:
                text = line.decode("utf-8-sig" if line_no == 1 else "utf-8")
            except UnicodeDecodeError as exc:
                raise InputError(where, None, f"not UTF-8 text: byte 0x{line[exc.start]:02x} at "
                                 f"column {exc.start + 1} (save the file as UTF-8)") from None
            record = parse_json_text(text, where)
        except InputError as exc:
            if explicit:
                orphans.append(str(exc))
            else:
                by_frame[order], line_of[order] = str(exc), line_no
            continue
        index = order
        if explicit:
            index = record.get("frame_index") if isinstance(record, dict) else None
            if (not isinstance(index, int) or isinstance(index, bool)
                    or not 0 <= index <= MAX_FRAME_INDEX):
                orphans.append(str(InputError(where, "frame_index", "expected a frame number from "
                                              f"0 to {MAX_FRAME_INDEX}, got {brief(index)}")))
                continue
        if index in by_frame:
            orphans.append(str(InputError(where, "frame_index",
                                          f"frame {index} already has a metadata line")))
            continue
        line_of[index] = line_no
        try:
            if isinstance(record, dict):
                record.setdefault("image", f"{video_stem}-{index:06d}.png")
            by_frame[index], time_error = parse_frame_metadata_untimed_on_error(
                record, where, camera=camera, base_dir=path.parent)
            if time_error is not None:
                time_errors[index] = time_error
        except InputError as exc:
            by_frame[index] = str(exc)
        except Exception as exc:  # one bad line must not end the run
            by_frame[index] = f"{where}: unexpected {type(exc).__name__}: {exc}"
    return by_frame, orphans, line_of, time_errors


def video_rotation_deg(capture) -> float:
    """The rotation a video's container asks players for (a phone's display matrix or
    ``rotate`` tag); 0 when none."""
    value = capture.get(cv2.CAP_PROP_ORIENTATION_META)
    return float(value) % 360.0 if math.isfinite(value) else 0.0


def open_video(video: Path) -> cv2.VideoCapture:
    """An opened capture of ``video`` that reads its frames as stored: OpenCV's
    auto-rotation is turned off, so that a container asking players to turn the picture
    does not turn the camera's pixels away from what the metadata describes (a picture
    turned by 180 degrees keeps its size, so nothing else would notice). :class:`InputError`
    when it cannot be opened, or where this OpenCV keeps turning such a video."""
    capture = cv2.VideoCapture(str(video))
    if not capture.isOpened():
        raise InputError(video, None, "cannot open the video (unknown format or corrupt)")
    turned = video_rotation_deg(capture)
    if turned:
        capture.set(cv2.CAP_PROP_ORIENTATION_AUTO, 0)
        if capture.get(cv2.CAP_PROP_ORIENTATION_AUTO) != 0:
            capture.release()
            raise InputError(video, "rotation", f"the container asks players to turn the "
                             f"picture {turned:g} degrees, and this OpenCV turns it as it reads "
                             "it, so the frames are not the camera's pixels that the metadata "
                             "describes; re-mux the video without its rotation")
    return capture


def video_frame_times_s(video: Path) -> np.ndarray | None:
    """Each frame's presentation time (s from the first) in display order, from the
    container's packets (PyAV, no decoding); None when the stream's packets carry no times
    (a raw elementary stream) or it cannot be read."""
    found = video_packet_times(video)
    if found is None:
        return None
    pts, base_s = found
    times = np.array(pts, float) * base_s
    return times - times[0]


class VideoSource:
    """A video file and its per-frame metadata (module docstring)."""

    def __init__(self, video: Path, metadata: Path, camera: CameraIntrinsics | None = None):
        self.video = video
        self.metadata = metadata
        if not video.is_file():
            raise InputError(video, None, "video file not found")
        capture = open_video(video)
        #: the display rotation the container asks for (the frames are read as stored)
        self.rotation_deg = video_rotation_deg(capture)
        self.container_fps = plausible_fps(capture.get(cv2.CAP_PROP_FPS))
        count = capture.get(cv2.CAP_PROP_FRAME_COUNT)
        self.frame_count = int(count) if math.isfinite(count) and count > 0 else 0
        width, height = (capture.get(p) for p in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT))
        #: (width, height) of the frames, where the container says it
        self.size = ((int(width), int(height)) if all(math.isfinite(v) and v >= 1
                                                      for v in (width, height)) else None)
        capture.release()
        self.by_frame, self.orphans, self.line_of, self.time_errors = read_metadata_lines(
            metadata, video.stem, camera)
        #: run-level warnings about the video (its decoder cannot report damaged data)
        self.warnings = [note for note in (damage_detection_note(video),) if note]
        # the annotated video's rate: the container's, else the metadata's timestamps
        self.fps = self.container_fps or fps_from_timestamps(
            _meta_timestamp_s(entry) for entry in self.by_frame.values())

    def frames(self) -> Iterator[FlightFrame]:
        """Metadata lines that name no frame first (index -1, reported), then every video
        frame, then the metadata of frames past the video's end."""
        for message in self.orphans:
            yield FlightFrame(-1, str(self.metadata), meta_path=self.metadata, error=message,
                              is_frame=False)
        last_index = -1
        last_raw_s = previous_s = None
        step_s = 1.0 / self.container_fps if self.container_fps else None
        for picture in read_video_frames(self.video):
            index = last_index = picture.index
            # the frame's presentation time; where the container gives none, or one that
            # does not increase (a repeated time), a frame interval after the previous
            # frame's (the index over the mean rate before any)
            raw_s = picture.time_s
            if raw_s is not None and (last_raw_s is None or raw_s > last_raw_s):
                video_time_s = last_raw_s = raw_s
            elif previous_s is not None and step_s is not None:
                video_time_s = previous_s + step_s
            else:
                video_time_s = index * step_s if step_s is not None else None
            previous_s = video_time_s
            entry = self.by_frame.get(index)
            frame = FlightFrame(index, f"{self.video} frame {index}", image=picture.image,
                                meta_path=self.metadata, video_time_s=video_time_s)
            if entry is None:
                frame.error = NO_METADATA if picture.damaged is None else (
                    f"{frame.source}: {picture.damaged}")
            elif isinstance(entry, str):
                frame.error = entry
            else:
                frame.meta, frame.time_error = entry, self.time_errors.get(index)
                where = f"{self.metadata}:{self.line_of[index]} (video frame {index})"
                if picture.damaged is not None:
                    frame.error = f"{where}: {picture.damaged}"
                else:
                    try:
                        check_image_size(picture.image, entry, where)
                    except InputError as exc:
                        frame.error = str(exc)
            yield frame
        index = last_index
        decoded = index + 1
        end = (f"past the video's end ({decoded} frames)" if decoded >= self.frame_count else
               f"past the last frame that could be decoded ({decoded} of the {self.frame_count} "
               f"its header counts: the video may be truncated or corrupt)")
        for missing in sorted(i for i in self.by_frame if i > index):
            where = f"{self.metadata}:{self.line_of[missing]}"
            yield FlightFrame(missing, where, meta_path=self.metadata, is_frame=False,
                              error=f"{where}: metadata for frame {missing}, {end}")


def plausible_fps(value: float | None) -> float | None:
    """A container's frame rate if it is one a camera records at (0.1 to 1000 fps); None for
    0, NaN or a time base passed off as a rate (90000 in some MPEG-TS files)."""
    if value is None or not math.isfinite(value) or not 0.1 <= value <= 1000.0:
        return None
    return float(value)


def _meta_timestamp_s(entry: FrameMetadata | str) -> float | None:
    """A metadata line's timestamp in seconds; None for a line in error or a bad time (the
    frame's own measurement reports those)."""
    if isinstance(entry, str):
        return None
    try:
        return timestamp_seconds(entry)
    except InputError:
        return None
