"""Hand-built int8 models whose fused integer arithmetic saturates on x86 CPUs without VNNI,
for the tests of ``--exact-int8`` (test_networks, test_segment_images)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: their input size; every pixel of a white frame is the same
HEIGHT, WIDTH = 4, 8
#: their logits on a white frame, as the graph defines them: class 0 sums 4 x 255 x 64 (no
#: 16-bit pair overflows), class 1 4 x 255 x 127 (every pair of products, 2 x 32,385,
#: overflows a 16-bit sum), class 2 nothing; each on an output step of 600
OUT_SCALE = 600.0
EXACT_LOGITS = [round(4 * 255 * w / OUT_SCALE) * OUT_SCALE for w in (64, 127, 0)]


def _weights(channels: int) -> np.ndarray:
    """int8 1x1 convolution weights: class 0 all 64, class 1 all 127, class 2 zero."""
    weights = np.zeros((3, channels, 1, 1), np.int8)
    weights[0], weights[1] = 64, 127
    return weights


def _save(path: Path, name: str, middle: list, constants: dict) -> Path:
    """A harborsight-shaped graph (uint8 ``image`` (1, H, W, 3) in, as NCHW float ``x``;
    ``logits`` and ``labels`` out) around the nodes ``middle``, which turn ``x`` into
    ``logits``; ``constants`` are its initialisers beside the shared scales and zero points."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    nodes = [helper.make_node("Cast", ["image"], ["f"], to=TensorProto.FLOAT),
             helper.make_node("Transpose", ["f"], ["x"], perm=[0, 3, 1, 2]),
             *middle,
             helper.make_node("ArgMax", ["logits"], ["best"], axis=1, keepdims=0),
             helper.make_node("Cast", ["best"], ["labels"], to=TensorProto.UINT8)]
    constants = {"one": np.array(1.0, np.float32), "zero_u8": np.array(0, np.uint8),
                 "zero_s8": np.array(0, np.int8), "out_scale": np.array(OUT_SCALE, np.float32),
                 **constants}
    graph = helper.make_graph(
        nodes, name,
        [helper.make_tensor_value_info("image", TensorProto.UINT8, [1, HEIGHT, WIDTH, 3])],
        [helper.make_tensor_value_info("logits", TensorProto.FLOAT, None),
         helper.make_tensor_value_info("labels", TensorProto.UINT8, None)],
        [numpy_helper.from_array(v, k) for k, v in constants.items()])
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), str(path))
    return path


def saturating_qdq_model(path: Path) -> Path:
    """One quantised 1x1 convolution (QDQ) over four uint8 channels (the frame's three and its
    first again). Its exact labels on a white frame are ship (1); where pairs of products
    saturate at 32,767, class 1 falls to class 0's logit and the tie goes to water (0)."""
    from onnx import helper

    middle = [
        helper.make_node("Concat", ["x", "x"], ["x6"], axis=1),
        helper.make_node("Slice", ["x6", "start", "stop", "axis"], ["x4"]),
        helper.make_node("QuantizeLinear", ["x4", "one", "zero_u8"], ["xq"]),
        helper.make_node("DequantizeLinear", ["xq", "one", "zero_u8"], ["xd"]),
        helper.make_node("DequantizeLinear", ["wq", "one", "zero_s8"], ["wd"]),
        helper.make_node("Conv", ["xd", "wd"], ["y"]),
        helper.make_node("QuantizeLinear", ["y", "out_scale", "zero_u8"], ["yq"]),
        helper.make_node("DequantizeLinear", ["yq", "out_scale", "zero_u8"], ["logits"]),
    ]
    return _save(path, "saturating", middle, {
        "wq": _weights(4), "start": np.array([0]), "stop": np.array([4]), "axis": np.array([1])})


def qoperator_model(path: Path) -> Path:
    """A like convolution in ONNX Runtime's QOperator format: one ``QLinearConv``, an integer
    operator that no session option turns into float arithmetic."""
    from onnx import helper

    middle = [
        helper.make_node("QuantizeLinear", ["x", "one", "zero_u8"], ["xq"]),
        helper.make_node("QLinearConv", ["xq", "one", "zero_u8", "wq", "one", "zero_s8",
                                         "out_scale", "zero_u8"], ["yq"]),
        helper.make_node("DequantizeLinear", ["yq", "out_scale", "zero_u8"], ["logits"]),
    ]
    return _save(path, "qoperator", middle, {"wq": _weights(3)})
