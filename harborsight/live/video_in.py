"""The drone's live video: an RTSP, RTMP, SRT, UDP (MPEG-TS or RTP), HTTP URL or a capture
device (``/dev/video0``, or its number), decoded by OpenCV's FFmpeg back-end (V4L2 for
devices) with low-delay flags: no input buffering, and an open and read timeout so that a
stream that stops is noticed instead of blocking the reader.

A stream that cannot be opened, that drops, or that stops sending is warned about and opened
again every ``retry_s`` until the live aid stops; a change of resolution is warned about (the
frames are still passed on: the camera's intrinsics follow the size where they come from a
preset, and a calibration of another size refuses the frame with the reason).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable

import cv2

from harborsight.flight.sources import FlightFrame
from harborsight.live.stream import Arrival, LatestFrame

STREAM_SCHEMES = ("rtsp://", "rtsps://", "rtmp://", "rtp://", "udp://", "srt://", "tcp://",
                  "http://", "https://")
#: FFmpeg input options for a live source (OpenCV reads them from this variable at open)
LOW_DELAY_OPTIONS = "fflags;nobuffer|flags;low_delay|rtsp_transport;tcp|fifo_size;1000000|overrun_nonfatal;1"


def is_stream(source: str) -> bool:
    """A URL or a capture device (anything else is a file)."""
    return source.lower().startswith(STREAM_SCHEMES) or source.startswith("/dev/video") or source.isdigit()


def _open(source: str, open_timeout_s: float, read_timeout_s: float) -> cv2.VideoCapture:
    params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, int(open_timeout_s * 1000),
              cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(read_timeout_s * 1000)]
    if source.isdigit() or source.startswith("/dev/video"):
        device = int(source) if source.isdigit() else source
        return cv2.VideoCapture(device, cv2.CAP_ANY)
    os.environ.setdefault("OPENCV_FFMPEG_CAPTURE_OPTIONS", LOW_DELAY_OPTIONS)
    return cv2.VideoCapture(source, cv2.CAP_FFMPEG, params)


def read_stream(source: str, box: LatestFrame, stop: threading.Event,
                on_arrival: Callable[[FlightFrame, float], None] | None = None,
                warn: Callable[[str], None] | None = None, *, retry_s: float = 1.0,
                open_timeout_s: float = 5.0, read_timeout_s: float = 2.0) -> None:
    """Read ``source`` into ``box`` until ``stop`` is set (module docstring). Frames are
    numbered from 0 over the whole session, across reconnections."""
    warn = warn or (lambda message: None)
    index = 0
    size: tuple[int, int] | None = None
    try:
        while not stop.is_set():
            capture = _open(source, open_timeout_s, read_timeout_s)
            if not capture.isOpened():
                warn(f"video: cannot open {source}; retrying every {retry_s:g} s")
                capture.release()
                stop.wait(retry_s)
                continue
            while not stop.is_set():
                ok, image = capture.read()
                if not ok or image is None:
                    warn(f"video: {source} stopped sending; reopening")
                    break
                now = time.monotonic()
                shape = (image.shape[1], image.shape[0])
                if size is not None and shape != size:
                    warn(f"video: the resolution changed from {size[0]}x{size[1]} to "
                         f"{shape[0]}x{shape[1]}")
                size = shape
                frame = FlightFrame(index=index, source=f"{source} frame {index}", image=image)
                if on_arrival is not None:
                    on_arrival(frame, now)
                box.put(Arrival(frame, now))
                index += 1
            capture.release()
            stop.wait(min(retry_s, 0.2))
    finally:
        box.close()
