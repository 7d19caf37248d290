"""Export a :class:`SegmentationModel` to ONNX, check it against torch, quantise to int8."""

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


def quantize_int8(
    onnx_path: str | Path, out_path: str | Path, calibration_images_bgr: np.ndarray
) -> Path:
    """Static int8 quantisation (QDQ, per-channel weights) calibrated on a few images."""
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class _Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self._items = iter([{"image": img[None]} for img in calibration_images_bgr])

        def get_next(self):
            return next(self._items, None)

    out_path = Path(out_path)
    prepared = out_path.with_suffix(".prep.onnx")
    quant_pre_process(str(onnx_path), str(prepared), skip_symbolic_shape=True)
    quantize_static(
        str(prepared), str(out_path), _Reader(), quant_format=QuantFormat.QDQ,
        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
        nodes_to_exclude=[n.name for n in onnx.load(str(prepared)).graph.node
                          if n.op_type in ("ArgMax", "Cast")],
    )
    prepared.unlink(missing_ok=True)
    quantized = onnx.load(str(out_path))
    float_classifier_tail(quantized)
    onnx.save(quantized, str(out_path))
    return out_path


def float_classifier_tail(model: onnx.ModelProto) -> int:
    """Drop the QuantizeLinear -> DequantizeLinear pairs from the last Conv (the classifier)
    on, in place; returns how many pairs went.

    Static quantisation puts the classifier's output, and the Resize and Slice after it, on
    a uint8 grid. Two classes then often tie, and ``ArgMax`` takes the lower index on a tie:
    water, the unsafe side, so ship and obstacle edges shrink. Without the pairs, ONNX
    Runtime runs the classifier in float (int8 weights dequantised) and the logits stay
    float; the backbone stays int8.
    """
    nodes = list(model.graph.node)
    last_conv = max((i for i, n in enumerate(nodes) if n.op_type == "Conv"), default=None)
    if last_conv is None:
        return 0
    producers = {out: node for node in nodes for out in node.output}
    consumers: dict[str, list] = {}
    for node in nodes:
        for name in node.input:
            consumers.setdefault(name, []).append(node)
    graph_outputs = {o.name for o in model.graph.output}
    removed = 0
    for node in nodes[last_conv:]:
        if node.op_type != "QuantizeLinear":
            continue
        followers = consumers.get(node.output[0], [])
        if len(followers) != 1 or followers[0].op_type != "DequantizeLinear":
            continue
        dequantize = followers[0]
        source, target = node.input[0], dequantize.output[0]
        if target in graph_outputs:
            # keep the output's name: the float tensor's producer writes it instead
            producer = producers[source]
            producer.output[list(producer.output).index(source)] = target
            for user in consumers.get(source, []):
                if user is not node:
                    user.input[list(user.input).index(source)] = target
        else:
            for user in consumers.get(target, []):
                for k, name in enumerate(user.input):
                    if name == target:
                        user.input[k] = source
        model.graph.node.remove(node)
        model.graph.node.remove(dequantize)
        removed += 1
    used = {name for node in model.graph.node for name in node.input}
    for unused in [t for t in model.graph.initializer if t.name not in used]:
        model.graph.initializer.remove(unused)
    return removed
