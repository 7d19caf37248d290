"""Damage a decoder does not report, seen in the pictures: a sudden local change.

FFmpeg's HEVC and VP9 decoders return no error and log nothing for damaged data (and H.264's
says nothing for a few damaged packets): a scrambled slice decodes into blocks displaced by
wrong motion vectors or filled with wrong residuals, and every later frame that predicts from
it carries them on until the next key frame. Such blocks disagree suddenly with the frame
before, where a drone's footage changes smoothly (the picture drifts, turns, zooms, brightens;
boats cross it).

Each frame is compared with the frame before it when both are whole: both reduced to grey
``THUMB_WIDTH_PX`` wide (area averaging), the earlier one shifted by the global translation
between them (phase correlation) and scaled to the later one's mean brightness; each
``BLOCK_PX`` square block's mean absolute difference, least over shifts of up to
``LOCAL_SHIFT_PX`` (a boat moving on its own); the frame's change ``c_t`` is the largest
block's (grey levels). A frame is **suspect** when

    c_t > SUDDEN_CHANGE_RATIO · median(c over the last HISTORY_FRAMES compared frames)

(at least ``MIN_HISTORY`` of them) and a block over that limit stays over it when it may
have moved up to ``MOVED_SHIFT_PX`` (a boat crossing fast, an edge leaving the picture); its
change does not join the history. The ratio is relative, so a video whose content moves
fast sets its own level. A cut to another scene, or an exposure that jumps in one frame
(1.25 times with highlights clipping), is named too: a false alarm that costs the frames
up to the next key frame.

What it catches is gross damage: blocks of garbage, regions moved far. Most damage a
scrambled HEVC packet leaves at 1080p is subtler (regions displaced by a few pixels, a tint)
and passes. Measured (docs/results.md, "Damage the decoder does not report, seen in the
pictures"): on clean clips cut from real drone photos and the bundled 2 fps flight
(hovering, panning, climbing, an exposure step, boats crossing slowly and fast, sun glint, a
2 fps drift that turns 0.4° a frame) no frame was suspect, the largest ratio 4.75; of the
frames of damaged 640x360 copies more than 1 % of whose pixels were over 30 grey levels
off, 65 % (HEVC) and 48 % (VP9) are now named, against 24 % and 2 % from the decoders'
logs; at 1080p, 7 % as before. Run only for decoders that report nothing themselves
(:data:`~harborsight.flight.video_decode.SILENT_DECODERS`).
"""

from __future__ import annotations

from collections import deque

import cv2
import numpy as np

#: the width (px) frames are reduced to before they are compared
THUMB_WIDTH_PX = 320
#: the side (px, of the reduced frame) of the blocks whose mean difference is compared
BLOCK_PX = 8
#: how many times the video's recent level a frame's change must be to be suspect
SUDDEN_CHANGE_RATIO = 5.0
#: the recent level: the median change over this many compared frames ...
HISTORY_FRAMES = 15
#: ... once at least this many were compared
MIN_HISTORY = 5
#: a margin (px of the reduced frame) left out of the comparison: what the shift brings in
EDGE_PX = 4
#: how far (px of the reduced frame) each block may move beyond the global translation: a
#: boat under way, or the water beside it, moves on its own
LOCAL_SHIFT_PX = 2
#: how far (px of the reduced frame) a block that changed suddenly is searched for before it
#: counts as unexplained by motion
MOVED_SHIFT_PX = 8
#: the top-left corner (px, both axes) of the blocks' grid in the reduced frame
GRID_ORIGIN_PX = EDGE_PX + LOCAL_SHIFT_PX


def reduced_grey(frame) -> np.ndarray:
    """A PyAV video frame as grey, its longer side ``THUMB_WIDTH_PX`` (FFmpeg's area
    scaling), float32."""
    scale = THUMB_WIDTH_PX / max(frame.width, frame.height, 1)
    width = max(2 * BLOCK_PX, round(frame.width * scale))
    height = max(2 * BLOCK_PX, round(frame.height * scale))
    small = frame.reformat(width=width, height=height, format="gray", interpolation="AREA")
    return small.to_ndarray().astype(np.float32)


class SuddenChange:
    """The check of the module docstring over a video's frames in presentation order."""

    def __init__(self) -> None:
        self._previous: np.ndarray | None = None
        self._history: deque[float] = deque(maxlen=HISTORY_FRAMES)

    def forget_previous(self) -> None:
        """The frame before was damaged or missing: the next is not compared with it."""
        self._previous = None

    def check_frame(self, frame) -> str | None:
        """:meth:`check` for a PyAV video frame. A frame the check cannot read (a pixel
        format FFmpeg cannot turn grey) is not compared, and the next is not compared with
        it: the check never stops a video being read."""
        import av

        try:
            return self.check(reduced_grey(frame))
        except (av.error.FFmpegError, cv2.error, ValueError, ArithmeticError):
            self._previous = None
            return None

    def check(self, grey: np.ndarray) -> str | None:
        """Why the frame (:func:`reduced_grey`) is suspect, or None; it becomes the frame
        the next one is compared with."""
        previous, self._previous = self._previous, grey
        if previous is None or previous.shape != grey.shape or min(grey.shape) < 2 * BLOCK_PX:
            return None         # (reduced_grey's frames are at least 2 blocks on each side)
        changes, shifted = block_changes(previous, grey)
        change = float(changes.max())
        if not np.isfinite(change):
            return None
        if len(self._history) >= MIN_HISTORY:
            level = float(np.median(self._history))
            limit = SUDDEN_CHANGE_RATIO * level
            if level > 0 and change > limit:
                unexplained = [(row, col) for row, col in np.argwhere(changes > limit)
                               if moved_block_change(shifted, grey, row, col) > limit]
                if unexplained:
                    self._previous = None
                    return (f"its picture changed suddenly against the frame before ("
                            f"{len(unexplained)} block(s) up to {change:.0f} grey levels off, "
                            f"{change / level:.1f} times the video's recent change, not "
                            f"explained by motion): damaged data the decoder did not report")
        self._history.append(change)
        return None


def block_changes(earlier: np.ndarray, later: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each block's change (grey levels) between two reduced frames (module docstring): the
    ``BLOCK_PX`` block mean of ``|later - earlier'|``, least over the shifts of up to
    ``LOCAL_SHIFT_PX`` around the global translation, with ``earlier'`` the earlier frame
    shifted by it and scaled to the later one's mean brightness (the grid from
    ``GRID_ORIGIN_PX``). Also ``earlier'``."""
    (dx, dy), _ = cv2.phaseCorrelate(earlier, later)
    shift = np.float32([[1.0, 0.0, dx], [0.0, 1.0, dy]])
    shifted = cv2.warpAffine(earlier, shift, (later.shape[1], later.shape[0]),
                             borderMode=cv2.BORDER_REPLICATE)
    # the mean brightness matched (an exposure that moved); matching the spread too let a
    # clipped exposure step pass but named a third fewer damaged frames (docs/results.md)
    shifted *= (float(later.mean()) + 1e-3) / (float(shifted.mean()) + 1e-3)
    margin = GRID_ORIGIN_PX
    height, width = later.shape
    # at least one block, its shifts inside the frame, for frames of 2 blocks or more
    rows = max(1, (height - 2 * margin) // BLOCK_PX)
    cols = max(1, (width - 2 * margin) // BLOCK_PX)
    bottom, right = margin + rows * BLOCK_PX, margin + cols * BLOCK_PX
    target = later[margin:bottom, margin:right]
    least = None
    for sy in range(-LOCAL_SHIFT_PX, LOCAL_SHIFT_PX + 1):
        for sx in range(-LOCAL_SHIFT_PX, LOCAL_SHIFT_PX + 1):
            moved = shifted[margin + sy:bottom + sy, margin + sx:right + sx]
            # block means: an area resize by a whole factor averages each block exactly
            blocks = cv2.resize(cv2.absdiff(target, moved), (cols, rows),
                                interpolation=cv2.INTER_AREA)
            least = blocks if least is None else np.minimum(least, blocks, out=least)
    return least, shifted


def moved_block_change(shifted: np.ndarray, later: np.ndarray, row: int, col: int) -> float:
    """The least mean ``|later - shifted|`` of one block over every shift of up to
    ``MOVED_SHIFT_PX``: what is left of its change when it may have moved on its own (a boat
    crossing fast, an edge leaving the picture)."""
    top, left = GRID_ORIGIN_PX + row * BLOCK_PX, GRID_ORIGIN_PX + col * BLOCK_PX
    block = later[top:top + BLOCK_PX, left:left + BLOCK_PX]
    height, width = shifted.shape
    y0, x0 = max(0, top - MOVED_SHIFT_PX), max(0, left - MOVED_SHIFT_PX)
    y1 = min(height, top + BLOCK_PX + MOVED_SHIFT_PX)
    x1 = min(width, left + BLOCK_PX + MOVED_SHIFT_PX)
    window = shifted[y0:y1, x0:x1]
    if window.shape[0] < BLOCK_PX or window.shape[1] < BLOCK_PX:
        return float(np.abs(block - shifted[top:top + BLOCK_PX, left:left + BLOCK_PX]).mean())
    views = np.lib.stride_tricks.sliding_window_view(window, block.shape)
    return float(np.abs(views - block).mean(axis=(2, 3)).min())
