"""harborsight: per-section hull clearance from a companion drone's camera.

The deployed path is numpy + OpenCV (+ ONNX Runtime for segmentation); see
``docs/geometry.md`` for the frame chain and the distance maths.
"""

__version__ = "0.1.0"
