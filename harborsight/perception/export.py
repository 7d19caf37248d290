"""Export a :class:`SegmentationModel` to ONNX and check it against torch (int8:
:mod:`harborsight.perception.quantization`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch

from harborsight.perception.model import SegmentationModel, _ExportGraph

OPSET = 17
METADATA_KEY = "harborsight"


def export_onnx(
    model: SegmentationModel, path: str | Path, height: int, width: int,
    metadata: dict | None = None, opset: int = OPSET,
) -> Path:
    """Write ``image`` uint8 (1, H, W, 3) BGR -> ``logits`` (1, C, H, W), ``labels`` (1, H, W).

    ``metadata`` (JSON-serialisable) is stored under the model's ``harborsight`` metadata key.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    was_training = model.training
    model.eval()
    dummy = torch.zeros(1, height, width, 3, dtype=torch.uint8)
    with torch.no_grad():
        torch.onnx.export(
            _ExportGraph(model), (dummy,), str(path), dynamo=False, opset_version=opset,
            input_names=["image"], output_names=["logits", "labels"],
        )
    proto = onnx.load(str(path))
    info = {"input_height": height, "input_width": width, "opset": opset,
            "output_stride": model.output_stride, **(metadata or {})}
    entry = proto.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, json.dumps(info)
    onnx.save(proto, str(path))
    model.train(was_training)
    return path


def onnx_max_abs_difference(model: SegmentationModel, path: str | Path, images_bgr: np.ndarray) -> float:
    """Largest |logit difference| between torch and ONNX Runtime over images (N, H, W, 3)."""
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    model.eval()
    worst = 0.0
    with torch.no_grad():
        for image in images_bgr:
            ours = model(torch.from_numpy(image[None])).numpy()
            theirs = session.run(["logits"], {"image": image[None]})[0]
            worst = max(worst, float(np.abs(ours - theirs).max()))
    return worst
