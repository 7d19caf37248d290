"""Frames for the live aid, newest first: a reader thread puts each decoded frame into a
one-frame slot; the measuring loop takes whatever is newest. A frame not taken before the
next one arrives is dropped (and counted), so the latency never grows with time.

:func:`replay_video` is the reader for a recorded flight (``--video FILE --metadata
flight.jsonl``): the video's frames with their metadata lines, at the video's own frame rate
with ``realtime`` (a replay behaves like a stream: frames come on time whether or not the
measurement keeps up), else as fast as they decode.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2

from harborsight.flight.sources import FlightFrame, VideoSource, open_video
from harborsight.flight.video_decode import read_video_frames


@dataclass
class Arrival:
    """A frame as it arrived: the frame and the monotonic time it came."""

    frame: FlightFrame
    arrived_s: float


class LatestFrame:
    """A one-frame mailbox: :meth:`put` replaces what is there (counting the drop),
    :meth:`take` waits for a frame, returns it and empties the box."""

    def __init__(self) -> None:
        self._condition = threading.Condition()
        self._item: Arrival | None = None
        self._closed = False
        self.dropped = 0
        self.received = 0

    def put(self, item: Arrival) -> None:
        with self._condition:
            if self._item is not None:
                self.dropped += 1
            self._item = item
            self.received += 1
            self._condition.notify_all()

    def close(self) -> None:
        """No more frames: :meth:`take` returns None once the box is empty."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()

    def take(self, timeout_s: float | None = None) -> Arrival | None:
        """The newest frame (waiting up to ``timeout_s``), or None when none came in time
        or the stream has ended."""
        with self._condition:
            if self._item is None and not self._closed:
                self._condition.wait(timeout_s)
            item, self._item = self._item, None
            return item

    @property
    def closed(self) -> bool:
        with self._condition:
            return self._closed and self._item is None


class VideoFrames:
    """A video file's frames without metadata (their poses come from the live feeds): a
    source for :func:`replay_video`, to rehearse a stream from a file."""

    def __init__(self, video: Path) -> None:
        capture = open_video(video)
        self.video, self.fps = video, capture.get(cv2.CAP_PROP_FPS) or None
        capture.release()

    def frames(self) -> Iterator[FlightFrame]:
        """Every frame; one decoded from damaged data carries the reason in ``error`` and
        one that gave no picture comes without an image (:mod:`harborsight.flight.video_decode`)."""
        for picture in read_video_frames(self.video):
            source = f"{self.video} frame {picture.index}"
            yield FlightFrame(index=picture.index, source=source, image=picture.image,
                              error=None if picture.damaged is None
                              else f"{source}: {picture.damaged}")


def replay_video(source: VideoSource | VideoFrames, box: LatestFrame, stop: threading.Event,
                 realtime: bool = True,
                 on_arrival: Callable[[FlightFrame, float], None] | None = None) -> None:
    """Read ``source``'s frames into ``box`` until the video ends or ``stop`` is set; with
    ``realtime`` each frame is put in at its time in the video (its index over the frame
    rate) after the first. ``on_arrival(frame, now_s)`` is called for every frame read,
    before it goes into the box (the health of the sources counts it there)."""
    fps = source.fps or 10.0
    started = time.monotonic()
    try:
        for frame in source.frames():
            if stop.is_set():
                break
            if frame.image is None:          # metadata without a picture: nothing to show
                continue
            if realtime:
                due = started + frame.index / fps
                wait = due - time.monotonic()
                if wait > 0 and stop.wait(wait):
                    break
            now = time.monotonic()
            if on_arrival is not None:
                on_arrival(frame, now)
            box.put(Arrival(frame, now))
    finally:
        box.close()
