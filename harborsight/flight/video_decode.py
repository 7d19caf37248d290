"""Video frames decoded with PyAV (FFmpeg), each with whether its picture can be trusted.

A video damaged in the middle (an SD card's bad block, a recording cut by a power loss and
repaired, packets lost on a UDP or RTP link) still decodes: the decoder conceals what it
could not read by copying and smearing blocks, and every later frame that predicts from the
damaged one carries the damage on until the next key frame. Measured on a 320x180 H.264
clip with one key frame's bytes scrambled in an MPEG-TS: 30 frames decoded without any
error returned or flag set, their mean difference from the clean decode growing from 3 to
30 grey levels; in an MP4 the same kind of damage made OpenCV's reader stop at the damaged
packet (the rest of the flight never read) and PyAV's raise for it. Both are wrong for a
measurement: a concealed frame shows water and quays where they are not, and a stop loses
every frame after it.

Frames are numbered by the rank of their presentation times among the file's packets, as
``telemetry video`` numbers the metadata it samples at those times; a packet lost from the
file altogether (an MPEG-TS packet holding a frame's header) leaves no time behind, and the
metadata paired by time stays with its picture.

So frames are decoded one packet at a time and a frame is **damaged** when

* a packet's decoding failed (FFmpeg's error for it), or the decoder logged an error
  while decoding it ("error while decoding MB", "concealing ... errors", a missing
  reference; not one about SEI side data, which leaves the picture whole), or FFmpeg
  flagged the frame corrupt; or
* a frame before it, in decoding order, was damaged or never came out (a packet of the
  file the decoder gave no picture for: its presentation time is never seen),

until a key frame decodes cleanly: from its presentation time on, frames are whole again.
Every frame output from the damaged packet on counts as damaged until then, those of earlier
presentation time too (a B-frame may predict from the damaged frame). Slice threading only,
so that the decoder's messages belong to the packet being decoded.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harborsight.errors import InputError

#: why a frame the file holds gave no picture
NOT_DECODED = "not decoded: its data is damaged or missing"


@dataclass
class DecodedPicture:
    """One decoded frame: its position in the video, the picture, and why it cannot be
    trusted (None when it can)."""

    index: int                       # the frame's rank among the video's presentation times
    time_s: float | None             # presentation time from the video's first frame
    image: np.ndarray | None         # BGR; None for a frame that never came out
    damaged: str | None = None


class DamageTracker:
    """Which frames show damaged data (module docstring); fed in decoding order."""

    def __init__(self) -> None:
        self.reason: str | None = None      # why frames are damaged now; None: whole
        self.damaged_packets = 0

    def packet(self, is_key: bool, error: str | None) -> None:
        """A packet was decoded (with ``error`` if it failed or the decoder complained)."""
        if error is not None:
            self.reason = error
            self.damaged_packets += 1
        elif is_key:
            self.reason = None

    def missing(self, reason: str) -> None:
        """A frame never came out: those predicting from it are damaged."""
        if self.reason is None:
            self.reason = reason


def decoded_frames(container, stream=None, tracker: DamageTracker | None = None
                   ) -> Iterator[tuple[object, str | None]]:
    """``(av.VideoFrame, damaged reason or None)`` of ``container``'s video stream in the
    order the decoder gives them (module docstring). Errors of reading the container (a
    dropped connection) are raised as :class:`OSError`; a packet that fails to decode is
    not. ``tracker`` (a new one if None) may be told of frames missed by the caller."""
    import av
    import av.logging as logging

    stream = stream if stream is not None else container.streams.video[0]
    codec = stream.codec_context
    codec.thread_type = "SLICE"
    tracker = tracker if tracker is not None else DamageTracker()
    level, skip = logging.get_level(), logging.get_skip_repeated()
    logging.set_level(logging.ERROR)
    logging.set_skip_repeated(False)      # each damaged packet says so, even in the same words
    try:
        with logging.Capture(local=False) as logs:
            for packet in container.demux(stream):
                frames, error = _decode(packet)
                complaints = [message.strip() for level_, name, message in logs
                              if level_ <= logging.ERROR and name == codec.name
                              and not _about_side_data(message)]
                del logs[:]
                if packet.size == 0:               # the end: the decoder's last frames
                    error = error or (complaints[0] if complaints else None)
                else:
                    tracker.packet(bool(packet.is_keyframe), None if error is None and not
                                   complaints else f"decoded from damaged data (packet at "
                                   f"{_time(packet, stream)}: {error or complaints[0]})")
                for frame in frames:
                    yield frame, _frame_damage(frame, tracker)
    except av.error.FFmpegError as exc:
        raise OSError(f"cannot read the video: {' '.join(str(exc).split())}") from None
    finally:
        logging.set_level(level)
        logging.set_skip_repeated(skip)


#: decoder messages about data beside the picture (H.264/HEVC SEI: user data, timecodes,
#: which drones fill with their own records): an error there leaves the picture whole, as
#: FFmpeg's decoders go on past it unless told to explode
_SIDE_DATA = re.compile(r"\bSEI\b")


def _about_side_data(message: str) -> bool:
    return _SIDE_DATA.search(message) is not None


def _decode(packet) -> tuple[list, str | None]:
    """The frames a packet gives, and FFmpeg's error if decoding it failed."""
    import av

    try:
        return list(packet.decode()), None
    except av.error.EOFError:
        return [], None
    except av.error.FFmpegError as exc:
        return [], " ".join((exc.strerror or str(exc)).split())


def _frame_damage(frame, tracker: DamageTracker) -> str | None:
    if getattr(frame, "is_corrupt", False) and tracker.reason is None:
        return "the decoder flagged the frame corrupt"
    return tracker.reason


def _time(packet, stream) -> str:
    if packet.pts is None or stream.time_base is None:
        return "unknown time"
    return f"{float(packet.pts * stream.time_base):.3f} s"


def video_packet_times(video: Path) -> tuple[list[int], float] | None:
    """The presentation times of every frame in the file, ascending, in the stream's time
    base, and that base in seconds; from the packets, without decoding. None when the
    packets carry no times (a raw elementary stream) or the file cannot be read."""
    import av

    try:
        with av.open(str(video)) as container:
            stream = container.streams.video[0]
            base = stream.time_base
            pts = [packet.pts for packet in container.demux(stream)
                   if packet.pts is not None and packet.size > 0]
    except (av.error.FFmpegError, IndexError, OSError, ValueError):
        return None
    if not pts or base is None:
        return None
    return sorted(pts), float(base)


def read_video_frames(video: Path) -> Iterator[DecodedPicture]:
    """Every frame of a video file in presentation order (module docstring), numbered by
    the rank of its presentation time among the file's packets, as ``telemetry video``
    numbers the metadata it pairs by those times: a frame the decoder never gives keeps its
    number (yielded with ``image`` None) and the frames after it keep theirs.
    :class:`InputError` when the file cannot be opened."""
    import av

    times, base = video_packet_times(video) or ([], None)
    number_of: dict[int, int] = {}
    for number, pts in enumerate(times):
        number_of.setdefault(pts, number)      # a time given twice: its first frame's number
    try:
        container = av.open(str(video))
    except (av.error.FFmpegError, OSError) as exc:
        raise InputError(video, None, f"cannot open the video ({' '.join(str(exc).split())})"
                         ) from None
    try:
        if not container.streams.video:
            raise InputError(video, None, "no video stream")
        stream = container.streams.video[0]
        first_pts = times[0] if times else None

        def lost(first: int, end: int) -> Iterator[DecodedPicture]:
            for number in range(first, end):
                yield DecodedPicture(number, _seconds(times[number], first_pts, base), None,
                                     NOT_DECODED)

        tracker = DamageTracker()
        expected = 0                           # the next frame's number
        for frame, damaged in decoded_frames(container, stream, tracker):
            number = number_of.get(frame.pts, expected) if frame.pts is not None else expected
            if number > expected:              # frames that gave no picture
                yield from lost(expected, number)
                if damaged is None and not frame.key_frame:
                    missed = (f"frame {expected}" if number == expected + 1
                              else f"frames {expected}-{number - 1}")
                    damaged = (f"decoded after {missed}, which gave no picture (it may "
                               "predict from them)")
                    tracker.missing(damaged)
            number = max(number, expected)     # a time seen twice: keep the numbering going
            expected = number + 1
            yield DecodedPicture(number, _seconds(frame.pts, first_pts, base),
                                 frame.to_ndarray(format="bgr24"), damaged)
        yield from lost(expected, len(times))
    except OSError as exc:
        raise InputError(video, None, str(exc)) from None
    finally:
        container.close()


def _seconds(pts: int | None, first_pts: int | None, base: float | None) -> float | None:
    if pts is None or first_pts is None or base is None:
        return None
    value = (pts - first_pts) * base
    return value if math.isfinite(value) else None
