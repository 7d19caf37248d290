"""Test-time flips: the model sees a frame and flipped copies of it, each copy's class
probabilities are flipped back, and their mean is the prediction (a nadir view of a harbour
has no up or left, so a network's mistakes on a frame and on its mirror image are partly
independent)."""

from __future__ import annotations

from harborsight.errors import InputError

#: test-time flips (mirrored left-right, upside down) by how many copies of a frame the
#: model sees: 1 the frame alone; 2 and its mirror image; 4 and both upside down (a nadir
#: view has no up; an oblique one with a horizon should use 2). The shipped model (int8, this
#: VM, ``--mode auto``) with 1 / 2 / 4: lake-shore photos (val) 64.7 / 65.4 / 66.2 % mIoU,
#: marina tiles 65.4 / 65.0 / 66.3, photo tiles 57.3 / 57.8 / 57.9, the seed-7 bench's
#: frames 0-259 94.72 / 95.01 / 95.12 (docs/results.md), at 1 / 2 / 4 times the model's time
FLIP_VIEWS = {1: ((False, False),), 2: ((False, False), (True, False)),
              4: ((False, False), (True, False), (False, True), (True, True))}


def flip_views(flips: int) -> tuple[tuple[bool, bool], ...]:
    """The (mirror, upside down) copies of :data:`FLIP_VIEWS` for ``flips``."""
    if flips not in FLIP_VIEWS:
        raise InputError(None, "--flips", f"expected one of {sorted(FLIP_VIEWS)}, got {flips}")
    return FLIP_VIEWS[flips]


class FlippedSegmenter:
    """A segmenter (an :class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter`) whose
    ``segment`` and ``segment_with_confidence`` run with ``flips``, for the pipelines that
    hand it a frame alone (``run``, ``evaluate distance``); anything else is the wrapped
    segmenter's."""

    def __init__(self, segmenter, flips: int) -> None:
        flip_views(flips)
        self._segmenter, self.flips = segmenter, flips

    def __getattr__(self, name: str):
        if name.startswith("__") or name == "_segmenter":   # copy and pickle look these up first
            raise AttributeError(name)
        return getattr(self._segmenter, name)

    def segment(self, image_bgr):
        return self._segmenter.segment(image_bgr, self.flips)

    def segment_with_confidence(self, image_bgr):
        return self._segmenter.segment_with_confidence(image_bgr, self.flips)
