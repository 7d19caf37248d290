"""Static int8 quantisation of an exported ONNX segmentation model (ONNX Runtime, QDQ).

No torch here: the command line reads the calibration options without loading it.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np

from harborsight.errors import InputError

#: how the activations' int8 ranges are set from the calibration images: ``minmax`` spans
#: every value seen; ``percentile`` keeps the central ``percentile`` % of the values seen
#: (ONNX Runtime's histogram calibrator, asymmetric: ``(100 - percentile) / 2`` % cut from
#: each tail), so a few extreme activations do not coarsen the steps of all the others
CALIBRATION_METHODS = ("minmax", "percentile")
DEFAULT_CALIBRATION_PERCENTILE = 99.999


def check_calibration(method: str, percentile: float, method_field: str = "calibration_method",
                      percentile_field: str = "calibration_percentile") -> None:
    """Refuse an unknown calibration method or a percentile outside (50, 100] (the errors
    name ``method_field`` and ``percentile_field``: a command line passes its options)."""
    if method not in CALIBRATION_METHODS:
        raise InputError(None, method_field,
                         f"unknown {method!r}; choose from {', '.join(CALIBRATION_METHODS)}")
    if not (50.0 < percentile <= 100.0):       # NaN fails this too
        raise InputError(None, percentile_field, f"must be in (50, 100], got {percentile}")


def quantize_int8(
    onnx_path: str | Path, out_path: str | Path, calibration_images_bgr: np.ndarray,
    method: str = "minmax", percentile: float = DEFAULT_CALIBRATION_PERCENTILE,
) -> Path:
    """Static int8 quantisation (QDQ, per-channel weights) calibrated on a few images, the
    activation ranges by ``method`` (:data:`CALIBRATION_METHODS`)."""
    import onnx
    from onnxruntime.quantization import (
        CalibrationDataReader,
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    check_calibration(method, percentile)
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class _Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self._items = iter([{"image": img[None]} for img in calibration_images_bgr])

        def get_next(self):
            return next(self._items, None)

    out_path = Path(out_path)
    prepared = out_path.with_suffix(".prep.onnx")
    quant_pre_process(str(onnx_path), str(prepared), skip_symbolic_shape=True)
    calibrator = {"minmax": CalibrationMethod.MinMax,
                  "percentile": CalibrationMethod.Percentile}[method]
    excluded = [n.name for n in onnx.load(str(prepared)).graph.node if n.op_type in ("ArgMax", "Cast")]
    with contextlib.redirect_stdout(io.StringIO()):     # the histogram calibrator prints progress
        quantize_static(
            str(prepared), str(out_path), _Reader(), quant_format=QuantFormat.QDQ,
            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, per_channel=True,
            nodes_to_exclude=excluded, calibrate_method=calibrator,
            extra_options={"CalibPercentile": percentile} if method == "percentile" else {},
        )
    prepared.unlink(missing_ok=True)
    quantized = onnx.load(str(out_path))
    float_classifier_tail(quantized)
    onnx.save(quantized, str(out_path))
    return out_path


def float_classifier_tail(model) -> int:
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
