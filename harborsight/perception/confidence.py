"""How sure a model is that a pixel is solid: its softmax, read at any frame pixel.

A model gives logits ``l (C, h, w)`` on its own input grid; the frame's labels are the
argmax of those logits resized bilinearly to the frame (pixel centres aligned, as
:class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter` does). The probability that a
frame pixel ``(u, v)`` is solid (ship or obstacle, anything but water, class 0) is read from
the same interpolation, at that pixel only:

    x = (u + 0.5) · w / W - 0.5,   y = (v + 0.5) · h / H - 0.5
    l(u, v) = bilinear(l, x, y)          (edge pixels repeated outside the grid)
    p_solid = 1 - exp(l_0) / Σ_k exp(l_k)

so a clearance can look along a line of pixels without a softmax of the whole frame.
"""

from __future__ import annotations

import cv2
import numpy as np

WATER_CLASS = 0
_MAP_COLUMNS = 4096


def class_probabilities(logits: np.ndarray, axis: int = 0) -> np.ndarray:
    """The softmax of ``logits`` over their class ``axis``: ``exp(l - max l) / Σ exp(...)``."""
    weights = np.exp(logits - logits.max(axis=axis, keepdims=True))
    weights /= weights.sum(axis=axis, keepdims=True)
    return weights


class SolidConfidence:
    """The model's solid probability at frame pixels, from its logits on its own grid.

    ``logits``: float ``(C, h, w)``, class 0 water; ``frame_width`` x ``frame_height``: the
    frame the labels were made for."""

    def __init__(self, logits: np.ndarray, frame_width: int, frame_height: int) -> None:
        logits = np.asarray(logits, np.float32)
        if logits.ndim != 3 or logits.shape[0] < 2:
            raise ValueError(f"expected logits (C >= 2, h, w), got {logits.shape}")
        if frame_width < 1 or frame_height < 1:
            raise ValueError(f"frame size must be positive, got {frame_width}x{frame_height}")
        self.channels = logits.shape[0]
        # (h, w, C): one remap reads up to 4 channels at once
        self._grid = [np.ascontiguousarray(logits[i:i + 4].transpose(1, 2, 0))
                      for i in range(0, self.channels, 4)]
        self.grid_height, self.grid_width = logits.shape[1:]
        self.frame_width, self.frame_height = int(frame_width), int(frame_height)
        #: bool (H, W) of frame pixels without a picture (alpha 0): labelled 255 and solid,
        #: whatever the model made of their fill (set by :func:`harborsight.pipeline.frame_labels`)
        self.no_picture: np.ndarray | None = None

    def logits_at(self, uv: np.ndarray) -> np.ndarray:
        """Bilinear logits ``(N, C)`` at frame pixels ``uv (N, 2)`` (module docstring)."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        if len(uv) == 0:
            return np.zeros((0, self.channels), np.float32)
        x = ((uv[:, 0] + 0.5) * (self.grid_width / self.frame_width) - 0.5).astype(np.float32)
        y = ((uv[:, 1] + 0.5) * (self.grid_height / self.frame_height) - 0.5).astype(np.float32)
        # remap's maps are images (each side under 32767): the points in rows of _MAP_COLUMNS
        n = len(uv)
        columns = min(n, _MAP_COLUMNS)
        padded = -n % columns
        if padded:
            tail = np.zeros(padded, np.float32)
            x, y = np.concatenate((x, tail)), np.concatenate((y, tail))
        map_x, map_y = x.reshape(-1, columns), y.reshape(-1, columns)
        parts = [cv2.remap(grid, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                 .reshape(n + padded, -1)[:n] for grid in self._grid]
        return np.concatenate(parts, axis=1)

    def solid_probability(self, uv: np.ndarray) -> np.ndarray:
        """``1 - p_water`` at frame pixels ``uv (N, 2)``; NaN where a pixel is not finite."""
        uv = np.asarray(uv, float).reshape(-1, 2)
        finite = np.isfinite(uv).all(axis=1)
        probability = np.full(len(uv), np.nan)
        logits = self.logits_at(uv[finite]).astype(np.float64)
        if len(logits):
            logits -= logits.max(axis=1, keepdims=True)
            weights = np.exp(logits)
            probability[finite] = 1.0 - weights[:, WATER_CLASS] / weights.sum(axis=1)
        if self.no_picture is not None and finite.any():
            pixel = np.rint(uv[finite]).astype(int)
            inside = ((pixel >= 0) & (pixel < [self.frame_width, self.frame_height])).all(axis=1)
            blank = np.zeros(len(pixel), bool)
            blank[inside] = self.no_picture[pixel[inside, 1], pixel[inside, 0]]
            probability[np.flatnonzero(finite)[blank]] = 1.0
        return probability
