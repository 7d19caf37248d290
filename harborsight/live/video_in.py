"""The drone's live video: an RTSP, RTMP, SRT, UDP (MPEG-TS or RTP), HTTP URL or a capture
device (``/dev/video0``), decoded with PyAV (FFmpeg) with low-delay flags: no input
buffering, probing cut to 0.5 s of stream, and an open and a read timeout so that a stream
that stops is noticed instead of blocking the reader. (OpenCV's FFmpeg capture was tried
first: at 2 fps it took 4-5 s to open a UDP stream and then delivered the frames it had
buffered at once.)

A frame's arrival time is its presentation timestamp (PTS) mapped to this process's clock
by the least-delayed frame, as the telemetry feeds' times are
(:class:`harborsight.live.telemetry.ClockMap`), not the moment the decoder returned it: on a
busy machine a frame can leave the decoder a quarter of a second late, and that delay would
otherwise pass for the moment the picture was taken. A frame without a timestamp keeps the
moment it was decoded. A frame whose offset differs from the least one by more than
:data:`VIDEO_JUMP_S` starts the mapping again from itself, with a warning: timestamps that
step back (a restarted encoder), or that do not keep time (FFmpeg's own at a frame rate the
camera does not send), can then move a frame's time by that much at most.

Packets lost or damaged on the link are decoded as the decoder can, and every frame decoded
from damaged data, up to the next key frame decoded whole, is passed on with the reason in
its ``error`` and not measured (:mod:`harborsight.flight.video_decode`; the frames stay on
the dashboard); a packet that fails to decode no longer reopens the stream.

A stream that cannot be opened, that drops, or that stops sending is warned about and opened
again every ``retry_s`` until the live aid stops; a change of resolution is warned about (the
frames are still passed on: the camera's intrinsics follow the size where they come from a
preset, and a calibration of another size refuses the frame with the reason).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from harborsight.flight.sources import FlightFrame
from harborsight.flight.video_decode import SILENT_DECODERS, decoded_frames
from harborsight.live.stream import Arrival, LatestFrame
from harborsight.live.telemetry import ClockMap, worth_saying

STREAM_SCHEMES = ("rtsp://", "rtsps://", "rtmp://", "rtp://", "udp://", "srt://", "tcp://",
                  "http://", "https://")
#: seconds a frame's timestamp may disagree with the least-delayed frame's before the mapping
#: starts again from it (a decoder's backlog on a busy machine stays under it: 0.24 s seen)
VIDEO_JUMP_S = 0.5
#: FFmpeg input options for a live source
LOW_DELAY_OPTIONS = {"fflags": "nobuffer", "flags": "low_delay", "analyzeduration": "500000",
                     "probesize": "500000"}


def is_stream(source: str) -> bool:
    """A URL or a capture device (anything else is a file)."""
    return source.lower().startswith(STREAM_SCHEMES) or source.startswith("/dev/video")


#: how RTP travels from an RTSP server: interleaved in the TCP connection (the default: UDP
#: loses packets on a drone's radio link and through NAT), or UDP (servers without TCP)
RTSP_TRANSPORTS = ("tcp", "udp")


def _open(source: str, open_timeout_s: float, read_timeout_s: float, rtsp_transport: str = "tcp"):
    import av

    options = dict(LOW_DELAY_OPTIONS)
    if source.lower().startswith(("rtsp://", "rtsps://")):
        options["rtsp_transport"] = rtsp_transport
        options["reorder_queue_size"] = "0"      # hand on each packet, do not hold them back
    if source.lower().startswith("udp://"):
        options.update({"fifo_size": "1000000", "overrun_nonfatal": "1"})
    return av.open(source, format="v4l2" if source.startswith("/dev/video") else None,
                   options=options, timeout=(open_timeout_s, read_timeout_s))


def _codec_name(container) -> str | None:
    try:
        return container.streams.video[0].codec_context.name
    except (AttributeError, IndexError):
        return None


def read_stream(source: str, box: LatestFrame, stop: threading.Event,
                on_arrival: Callable[[FlightFrame, float], None] | None = None,
                warn: Callable[[str], None] | None = None, *, retry_s: float = 1.0,
                open_timeout_s: float = 5.0, read_timeout_s: float = 2.0,
                rtsp_transport: str = "tcp") -> None:
    """Read ``source`` into ``box`` until ``stop`` is set (module docstring). Frames are
    numbered from 0 over the whole session, across reconnections."""
    warn = warn or (lambda message: None)
    index = damaged_frames = 0
    said_silent = False
    size: tuple[int, int] | None = None
    try:
        while not stop.is_set():
            try:
                container = _open(source, open_timeout_s, read_timeout_s, rtsp_transport)
            except Exception as exc:      # FFmpeg's errors (av.error.*) and OSError
                warn(f"cannot open {source} ({exc}); retrying every {retry_s:g} s")
                stop.wait(retry_s)
                continue
            clock = ClockMap(jump_s=VIDEO_JUMP_S)   # a reopened stream numbers afresh
            codec = _codec_name(container)
            if codec in SILENT_DECODERS and not said_silent:
                said_silent = True
                warn(f"{source} is {SILENT_DECODERS[codec]}: its decoder does not report "
                     "damaged data, so a frame concealed after a lost packet is found only "
                     "where the stream flags it or the picture changes suddenly (gross "
                     "damage; blocks displaced by a few pixels pass)")
            try:
                for picture, damaged in decoded_frames(container):
                    now = time.monotonic()
                    if picture.time is not None:
                        jumps = clock.jumps
                        now = clock.observe(picture.time, now)
                        if clock.jumps > jumps and worth_saying(clock.jumps):
                            warn(f"the video's timestamps jumped by more than {VIDEO_JUMP_S:g} s "
                                 f"against this machine's clock ({clock.jumps} time(s)): frame "
                                 "times start again from the frame's arrival")
                    image = picture.to_ndarray(format="bgr24")
                    shape = (image.shape[1], image.shape[0])
                    if size is not None and shape != size:
                        warn(f"the resolution changed from {size[0]}x{size[1]} to "
                             f"{shape[0]}x{shape[1]}")
                    size = shape
                    frame = FlightFrame(index=index, source=f"{source} frame {index}", image=image)
                    if damaged is not None:     # measured, it would show what is not there
                        frame.error = f"{frame.source}: {damaged}"
                        damaged_frames += 1
                        if worth_saying(damaged_frames):
                            warn(f"{damaged_frames} frame(s) decoded from damaged data, not "
                                 f"measured (the last: {damaged})")
                    if on_arrival is not None:
                        on_arrival(frame, now)
                    box.put(Arrival(frame, now))
                    index += 1
                    if stop.is_set():
                        break
                else:
                    warn(f"{source} ended; reopening")
            except Exception as exc:      # a read timeout, a dropped connection, corrupt data
                warn(f"{source} stopped sending ({exc}); reopening")
            finally:
                container.close()
            stop.wait(min(retry_s, 0.2))
    finally:
        box.close()
