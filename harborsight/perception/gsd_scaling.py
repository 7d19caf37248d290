"""Segmenting a frame at a chosen ground sample distance (GSD): the measuring pipelines know
each frame's height and focal length, so they can show the model the harbour at the scale it
draws edges best at.

The model's input is fixed (640x360 for the default model) and a frame is normally stretched
into it: a nadir frame of width ``W`` and height ``H`` with ground sample distance ``g``
(:func:`~harborsight.geometry.gsd.nadir_gsd_m_per_px`) reaches the model at

    g_model = g · max(W / w_in, H / h_in)

metres per model pixel. The default model's edge error is about 2-5 model pixels at every
height (docs/results.md), so in metres it grows with ``g_model``: a 640x360 frame from
100 m (0.22 m/px with the Mavic 3 preset) loses the quay's edge by more than the 0.3 m the
flights ask for. With a target ``g_t`` the frame is scaled by

    s = g / g_t                                  (the model then sees g_t per pixel)

capped so that the scaled frame's longer side is at most :data:`MAX_SIDE_WINDOWS` model
inputs, and segmented in overlapping windows of the model input
(:func:`~harborsight.perception.segment_images.scaled_tile_logits`, tent-weighted blend).
Enlarged, a frame looks like a lower flight with a higher one's blur, which the model never
saw: on its own it paints some bollards and pier planks as ship. So the class probabilities
of the windows' blend ``p_w`` are mixed with those of the ordinary one-call view ``p_1``
(resized to the scaled grid),

    p = (1 - w) · p_w + w · p_1,          w = WHOLE_VIEW_WEIGHT

and ``log p`` gives the frame's labels and its model confidence. Where stretching already
gives ``g_model <= g_t`` the frame takes the ordinary one-call path, so small GSDs cost
nothing. ``g`` is the image centre's footprint along the tilt
(:func:`~harborsight.pipeline.frame_gsd_m_per_px`); a tilted view is coarser beyond its
centre and finer before it.

What it does not promise:

* "or finer" holds for the larger of the two axes' GSDs. Where stretching squeezes one axis
  more than the other (a 4:3 frame into 16:9), the one-call path sees that frame's other axis
  finer than ``g_t``. The tiles see both axes at ``g_t``.
* A frame switches between the one-call and the enlarged path where its stretched GSD
  crosses ``g_t · SCALE_TOLERANCE``. Over a climb or a descent through that height, the
  masks change their maker in one step.
* Where the windows and the whole view disagree, the mix caps the model's solid probability
  near ``1 - w``. An obstacle only the windows see is drawn, but never counts as sure
  (:data:`~harborsight.clearance.edge_evidence.CONFIDENT_SOLID_P`). It widens its section's
  sigma rather than narrowing it.

Off by default everywhere. On simulator frames it lowered the model's distance error at
every height it enlarged, but on the real val frames of ``data/real`` (given their nominal
GSDs) it did not help: the marina tiles (0.3 m/px, enlarged 2.5x) fell from 65.4 to 62.1 %
mIoU (ship 75.9 → 65.4 %), and the lake-shore photos (0.17 m/px, 1.42x) went 64.7 → 64.9 %
while patches of shaded lawn turned to water (docs/results.md).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from harborsight.errors import InputError
from harborsight.perception.confidence import SolidConfidence, class_probabilities
from harborsight.perception.flips import FlippedSegmenter

#: the scaled frame's longer side at most this many model inputs' (3 x 640 px for the default
#: model: at most 4 x 4 windows of 25 % overlap, 16 model calls)
MAX_SIDE_WINDOWS = 3.0
#: overlap of neighbouring windows, a fraction of a window (without it the seams cost the
#: 100 m flight 0.13 m of MAE: 0.470 against 0.344 m at a scale of 2, docs/results.md)
WINDOW_OVERLAP = 0.25
#: a frame whose stretched GSD is within this factor of the target takes the one-call path
SCALE_TOLERANCE = 1.05
#: share of the one-call view's probabilities in the mix (module docstring): on the seed-7
#: bench's frames 0-259 at 0.12 m/px, 0 (windows alone) / 0.3 / 0.5 gave a summed MAE over
#: 70-150 m of 9.41 / 8.65 / 8.52 m and medians of 0.23-0.39 / 0.23-0.41 / 0.29-0.46 m; on
#: the 100 m berthing flight 0.335 / 0.342 / 0.359 m filtered (docs/results.md)
WHOLE_VIEW_WEIGHT = 0.3


def check_segment_gsd(value_m: float | None, option: str = "--segment-gsd-m") -> float | None:
    """``value_m`` (metres per pixel, > 0 and finite), or None for 0 / None (off)."""
    if value_m is None or value_m == 0:
        return None
    if not (math.isfinite(value_m) and value_m > 0):
        raise InputError(None, option, f"expected a ground sample distance > 0 m per pixel "
                         f"(0: off), got {value_m}")
    return float(value_m)


def processing_scale(width_px: int, height_px: int, gsd_m_per_px: float | None,
                     target_gsd_m: float, input_width_px: int, input_height_px: int
                     ) -> float | None:
    """The scale ``s`` of a ``width_px`` x ``height_px`` frame of GSD ``gsd_m_per_px`` for
    the model to see it at ``target_gsd_m`` (module docstring), or None where stretching
    the frame into the model input already does (or the GSD is unknown)."""
    if gsd_m_per_px is None or not (math.isfinite(gsd_m_per_px) and gsd_m_per_px > 0):
        return None
    stretched_gsd_m = gsd_m_per_px * max(width_px / input_width_px, height_px / input_height_px)
    if stretched_gsd_m <= target_gsd_m * SCALE_TOLERANCE:
        return None
    scale = gsd_m_per_px / target_gsd_m
    longest_px = MAX_SIDE_WINDOWS * max(input_width_px, input_height_px)
    return min(scale, longest_px / max(width_px, height_px))


class GsdScaledSegmenter(FlippedSegmenter):
    """A segmenter for the measuring pipelines that shows the model each frame at
    ``target_gsd_m`` or finer (module docstring); ``flips`` as
    :class:`~harborsight.perception.flips.FlippedSegmenter`. Its ``segment`` and
    ``segment_with_confidence`` take the frame's GSD
    (:func:`~harborsight.pipeline.frame_gsd_m_per_px`); without it (None) a frame is
    segmented as by the wrapped segmenter."""

    #: the pipelines hand this segmenter each frame's GSD (:func:`harborsight.pipeline.frame_labels`)
    takes_gsd = True

    def __init__(self, segmenter, flips: int, target_gsd_m: float) -> None:
        super().__init__(segmenter, flips)
        target = check_segment_gsd(target_gsd_m)
        if target is None:
            raise InputError(None, "--segment-gsd-m", "a GSD-scaled segmenter needs a target > 0")
        self.target_gsd_m = target

    def scale_for(self, image_bgr: np.ndarray, gsd_m_per_px: float | None) -> float | None:
        """:func:`processing_scale` of this frame for the model's input."""
        height, width = image_bgr.shape[:2]
        return processing_scale(width, height, gsd_m_per_px, self.target_gsd_m,
                                self._segmenter.input_width, self._segmenter.input_height)

    def _scaled_logits(self, image_bgr: np.ndarray, scale: float) -> np.ndarray:
        """Log class probabilities ``(C, h, w)`` on the scaled grid: the windows' blend
        mixed with the one-call view (module docstring)."""
        from harborsight.perception.segment_images import (
            SegmentMode,
            SegmentOptions,
            scaled_tile_logits,
            small_frame_logits,
        )

        options = SegmentOptions(SegmentMode.tiles, tile_overlap=WINDOW_OVERLAP,
                                 tile_scale=scale, flips=self.flips)
        windows = scaled_tile_logits(self._segmenter, image_bgr, options)
        # the one-call view as the wrapped segmenter makes it (a frame smaller than the
        # input enlarged without stretching, any other stretched into it)
        whole = small_frame_logits(self._segmenter, image_bgr, self.flips)
        if whole is None:
            whole = self._segmenter.batch_logits(self._segmenter.fit(image_bgr)[None],
                                                 self.flips)[0]
        height, width = windows.shape[1:]
        whole = cv2.resize(np.ascontiguousarray(whole.transpose(1, 2, 0)), (width, height),
                           interpolation=cv2.INTER_LINEAR).reshape(height, width, -1)
        mixed = ((1.0 - WHOLE_VIEW_WEIGHT) * class_probabilities(windows)
                 + WHOLE_VIEW_WEIGHT * class_probabilities(whole.transpose(2, 0, 1)))
        return np.log(mixed + 1e-12).astype(np.float32)

    def segment(self, image_bgr: np.ndarray, gsd_m_per_px: float | None = None) -> np.ndarray:
        return self.segment_with_confidence(image_bgr, gsd_m_per_px)[0]

    def segment_with_confidence(self, image_bgr: np.ndarray, gsd_m_per_px: float | None = None
                                ) -> tuple[np.ndarray, SolidConfidence]:
        from harborsight.perception.onnx_segmenter import OnnxSegmenter

        scale = self.scale_for(image_bgr, gsd_m_per_px)
        if scale is None:
            return super().segment_with_confidence(image_bgr)
        height, width = image_bgr.shape[:2]
        logits = self._scaled_logits(image_bgr, scale)
        # labels read like the confidence (bilinear, pixel centres aligned), not area-averaged
        return OnnxSegmenter.frame_labels(logits, width, height), SolidConfidence(logits, width,
                                                                                    height)


def pipeline_segmenter(segmenter, flips: int = 1, segment_gsd_m: float | None = None):
    """``segmenter`` (an :class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter`) as
    the measuring pipelines use it: seeing each frame at ``segment_gsd_m`` or finer
    (:class:`GsdScaledSegmenter`), else with ``flips``
    (:class:`~harborsight.perception.flips.FlippedSegmenter`), else as it is."""
    target = check_segment_gsd(segment_gsd_m)
    if target is not None:
        return GsdScaledSegmenter(segmenter, flips, target)
    return segmenter if flips == 1 else FlippedSegmenter(segmenter, flips)
