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

* a packet's decoding failed (FFmpeg's error for it), the decoder logged an error while
  decoding it ("error while decoding MB", "concealing ... errors", a missing reference, a
  checksum the stream carries that disagrees; not one about SEI side data, which leaves the
  picture whole), the container flagged the packet corrupt (an MPEG-TS packet lost on a
  link), or FFmpeg flagged the frame corrupt; or
* its picture changed suddenly against the frame before, in blocks that no motion explains
  (:mod:`~harborsight.flight.sudden_change`: damage the decoder did not report); or
* a frame before it, in decoding order, was damaged or never came out (a packet of the
  file the decoder gave no picture for, or a longer step in a constant-rate video's times:
  a packet lost from the file leaves no time of its own),

until a key packet decodes cleanly and its own picture comes out (:class:`DamageTracker`:
frames of the damaged group a decoder with B-frames outputs after that packet stay named;
an intra-refresh stream's recovery point counts at the second one). Slice threading only,
so that the decoder's messages belong to the packet being decoded.

FFmpeg's HEVC and VP9 decoders report nothing for damaged data (:data:`SILENT_DECODERS`):
there damage is found only where the container flags it, a packet gives no picture or the
picture changes suddenly, and :func:`damage_detection_note` says so for the run.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.flight.sudden_change import SuddenChange

#: why a frame the file holds gave no picture
NOT_DECODED = ("not decoded: its data is damaged or missing (or it precedes the stream's "
               "first key frame)")
#: decoders that say nothing of damaged data (FFmpeg's HEVC and VP9 decoders log no error
#: and return none for scrambled packets; AV1 for some): in such a video damage is found
#: only where the container flags it, a packet gives no picture, or a stream's checksums
#: (HEVC picture hash SEI) disagree
SILENT_DECODERS = {"hevc": "HEVC (H.265)", "vp9": "VP9", "av1": "AV1", "libdav1d": "AV1"}


@dataclass
class DecodedPicture:
    """One decoded frame: its position in the video, the picture, and why it cannot be
    trusted (None when it can)."""

    index: int                       # the frame's rank among the video's presentation times
    time_s: float | None             # presentation time from the video's first frame
    image: np.ndarray | None         # BGR; None for a frame that never came out
    damaged: str | None = None


class DamageTracker:
    """Which frames show damaged data (module docstring); told of packets in decoding order
    and of frames as they come out.

    Damage ends with a key packet decoded whole, but only when that packet's own picture
    comes out: a decoder with B-frames still outputs the last frames of the damaged group
    after it (reorder delay), and open-GOP leading pictures (earlier in time) predict from
    before it. An intra-refresh stream's recovery points are key packets whose picture is a
    P frame that does not yet refresh the whole picture: there, damage ends at the second
    recovery point after it (one whole refresh period)."""

    def __init__(self) -> None:
        self.reason: str | None = None      # why frames are damaged now; None: whole
        self.damaged_packets = 0
        self._packets = 0                   # packets so far (decoding order)
        self._damaged_at = -1               # the packet the damage arose at
        self._refresh_at = -1               # a recovery point seen since the damage
        self._keys: dict[int, int] = {}     # clean key packets' times -> their packet number
        self._whole_from_pts: int | None = None      # the picture damage last ended at
        self._ended: str | None = None               # ... and why frames were damaged before

    def packet(self, is_key: bool, error: str | None, pts: int | None = None) -> None:
        """A packet was decoded (with ``error`` if it failed or the decoder complained)."""
        self._packets += 1
        if error is not None:
            self.reason, self._damaged_at = error, self._packets
            self.damaged_packets += 1
            self._keys.clear()
        elif is_key:
            self._keys[pts] = self._packets     # None: an untimed stream's (raw H.264)

    def seen(self, reason: str) -> None:
        """The frame that came out shows damage the decoder did not report
        (:mod:`~harborsight.flight.sudden_change`): it and the frames after it are damaged
        as from a damaged packet decoded before any key packet whose picture has not come
        out yet (a decoder with B-frames outputs a group's last frames after the next key
        packet; that key picture still ends the damage)."""
        pending = list(self._keys.values())
        self.reason = reason
        self._damaged_at = min(pending) - 1 if pending else self._packets
        self.damaged_packets += 1

    def missing(self, reason: str) -> None:
        """A frame never came out: those predicting from it are damaged."""
        if self.reason is None:
            self.reason, self._damaged_at = reason, self._packets
            self._keys.clear()

    def frame(self, pts: int | None, key_frame: bool, intra: bool, corrupt: bool
              ) -> str | None:
        """Why the frame that came out (its time, the decoder's key flag, whether it is an
        I picture, FFmpeg's corrupt flag) is damaged, or None."""
        # an untimed stream has one key slot: only a key picture may take it (a B-frame of
        # the damaged group output after the key packet would otherwise)
        number = self._keys.pop(pts, None) if pts is not None or key_frame else None
        if self.reason is not None and number is not None and number > self._damaged_at:
            whole = key_frame and intra
            if not whole and self._refresh_at > self._damaged_at:
                whole = True            # a second recovery point: refreshed since
            elif not whole:
                self._refresh_at = number
            if whole:
                self._ended, self.reason, self._whole_from_pts = self.reason, None, pts
        if self.reason is not None:
            return self.reason
        if self._ended is not None and pts is not None and self._whole_from_pts is not None:
            if pts < self._whole_from_pts:
                return self._ended      # a leading picture of the damaged group
            if pts > self._whole_from_pts:
                self._ended = None      # past them (times that later step back are not)
        return "the decoder flagged the frame corrupt" if corrupt else None


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
    # the pictures are checked only where the decoder says nothing of damaged data
    pictures = SuddenChange() if codec.name in SILENT_DECODERS else None
    codec.thread_type = "SLICE"
    # checksums a stream carries (HEVC's picture hash SEI) checked: a mismatch is logged
    codec.options = {**codec.options, "err_detect": "crccheck"}
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
                if error is None and complaints:
                    error = complaints[0]
                if error is None and packet.size and packet.is_corrupt:
                    error = "the container flagged the packet corrupt"    # a TS packet lost
                tracker.packet(bool(packet.is_keyframe) and packet.size > 0,
                               None if error is None else
                               f"decoded from damaged data (packet at {_time(packet, stream)}: "
                               f"{error})", packet.pts)
                for frame in frames:
                    damaged = tracker.frame(frame.pts, bool(frame.key_frame),
                                            _is_intra(frame), bool(frame.is_corrupt))
                    if pictures is not None and damaged is None:
                        damaged = pictures.check_frame(frame)
                        if damaged is not None:
                            tracker.seen(damaged)
                    elif pictures is not None:
                        pictures.forget_previous()
                    yield frame, damaged
    except av.error.FFmpegError as exc:
        raise OSError(f"cannot read the video: {' '.join(str(exc).split())}") from None
    finally:
        logging.set_level(level)
        logging.set_skip_repeated(skip)


def _is_intra(frame) -> bool:
    try:
        return int(frame.pict_type) == 1        # AV_PICTURE_TYPE_I
    except (TypeError, ValueError):
        return False


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
            # a packet before an edit list's start (a file trimmed without re-encoding) is
            # decoded as a reference, its picture discarded: not a frame of the video
            pts = [packet.pts for packet in container.demux(stream)
                   if packet.pts is not None and packet.size > 0 and not packet.is_discard]
    except (av.error.FFmpegError, IndexError, OSError, ValueError):
        return None
    if not pts or base is None:
        return None
    return sorted(pts), float(base)


def damage_detection_note(video: Path) -> str | None:
    """A warning for a video whose decoder does not report damaged data (:data:`SILENT_DECODERS`),
    or None."""
    import av

    try:
        with av.open(str(video)) as container:
            name = container.streams.video[0].codec_context.name
    except (av.error.FFmpegError, IndexError, OSError, ValueError):
        return None
    if name not in SILENT_DECODERS:
        return None
    return (f"{video}: {SILENT_DECODERS[name]} video: FFmpeg's decoder does not report damaged "
            "data, so a frame decoded from a damaged part of the file (a bad block, a repaired "
            "recording) is found only where the container flags it, a packet gives no "
            "picture or the picture changes suddenly where no motion explains it (gross "
            "damage: blocks of garbage; blocks displaced by a few pixels pass), and may be "
            "measured; H.264 reports it")


#: a video is taken for one of constant frame rate when 90 % of its frame steps lie within
#: 5 % of their median; a step of 1.5 medians or more is then a gap
REGULAR_STEP_SHARE, REGULAR_STEP_TOLERANCE, GAP_STEPS = 0.9, 0.05, 1.5


def times_after_a_gap(times: list[int]) -> set[int]:
    """The packet times that follow a gap in a constant-rate video: a packet lost from the
    file leaves no time of its own, only a longer step (a camera that skips a frame leaves
    one too, and costs the frames up to the next key frame)."""
    steps = np.diff(np.asarray(times, float))
    if len(steps) < 4:
        return set()
    step = float(np.median(steps))
    if step <= 0 or np.mean(np.abs(steps - step) <= REGULAR_STEP_TOLERANCE * step) < REGULAR_STEP_SHARE:
        return set()
    return {times[k + 1] for k in np.flatnonzero(steps >= GAP_STEPS * step)}


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
    after_gap = times_after_a_gap(times)
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
            if damaged is None and frame.pts in after_gap and not frame.key_frame:
                damaged = ("decoded after a gap in the video's frame times: a frame's packet "
                           "may be lost from the file, and it may predict from that frame")
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
