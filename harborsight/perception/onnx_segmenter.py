"""Deployed inference: an exported model in ONNX Runtime (numpy + OpenCV, no torch)."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from harborsight.errors import InputError


class OnnxSegmenter:
    """Runs a ``harborsight`` ONNX model on BGR frames of any size.

    The graph itself normalises, pads and crops (see :mod:`harborsight.perception.model`);
    frames whose size differs from the model's input are resized to it (area filter) and
    the labels resized back with nearest-neighbour.
    """

    def __init__(self, path: str | Path, threads: int | None = None) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise InputError(self.path, None, "model file not found")
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(self.path), options,
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:  # ORT raises its own exception types for bad files
            raise InputError(self.path, None, f"not a loadable ONNX model: {exc}") from exc
        meta = self.session.get_modelmeta().custom_metadata_map.get("harborsight")
        self.metadata = json.loads(meta) if meta else {}
        self.sidecar: dict = {}  # the export sidecar, filled by perception.default_model
        self.input_height, self.input_width = self._check_interface()

    def _check_interface(self) -> tuple[int, int]:
        """Reject graphs that are not a ``harborsight export``: one uint8 input ``image``
        (N, H, W, 3) with a fixed H and W, and outputs ``logits`` and ``labels``."""
        inputs = self.session.get_inputs()
        outputs = {o.name for o in self.session.get_outputs()}
        shape = inputs[0].shape if len(inputs) == 1 else []
        if (len(inputs) != 1 or inputs[0].name != "image" or inputs[0].type != "tensor(uint8)"
                or len(shape) != 4 or shape[3] != 3
                or not all(isinstance(d, int) for d in shape[1:3])):
            found = [(i.name, i.shape, i.type) for i in inputs]
            raise InputError(self.path, "inputs", "not a harborsight segmentation model: expected "
                             f"one uint8 input 'image' of shape (N, H, W, 3), found {found}")
        missing = {"logits", "labels"} - outputs
        if missing:
            raise InputError(self.path, "outputs", "not a harborsight segmentation model: "
                             f"missing output(s) {sorted(missing)}, found {sorted(outputs)}")
        return int(shape[1]), int(shape[2])

    def logits(self, image_bgr: np.ndarray) -> np.ndarray:
        """Float logits (C, H, W) at the model's input size."""
        image = self._fit(image_bgr)
        return self.session.run(["logits"], {"image": image[None]})[0][0]

    def segment(self, image_bgr: np.ndarray) -> np.ndarray:
        """uint8 class labels (H, W) at the frame's own size."""
        h, w = image_bgr.shape[:2]
        labels = self.session.run(["labels"], {"image": self._fit(image_bgr)[None]})[0][0]
        if labels.shape != (h, w):
            labels = cv2.resize(labels, (w, h), interpolation=cv2.INTER_NEAREST)
        return labels

    def _fit(self, image_bgr: np.ndarray) -> np.ndarray:
        if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise ValueError(f"expected a uint8 BGR image (H, W, 3), got {image_bgr.shape} "
                             f"{image_bgr.dtype}")
        if image_bgr.shape[:2] != (self.input_height, self.input_width):
            image_bgr = cv2.resize(image_bgr, (self.input_width, self.input_height),
                                   interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(image_bgr)
