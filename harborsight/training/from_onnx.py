"""Torch weights recovered from a harborsight ONNX model, so a shipped model can be fine-tuned.

We ship ONNX files, not checkpoints. To warm-start a run from one (``train --init-from
model.onnx``), its weights are read back into the network it was exported from:

1. Every weight initialiser is read; int8 weights behind ``DequantizeLinear`` are
   dequantised, ``w = (q - zero_point) * scale`` (per output channel).
2. The exporter folded each BatchNorm that directly follows a convolution into it
   (``W' = W * gamma / sigma``, ``b' = beta - mu * gamma / sigma``). The ONNX ``Conv`` nodes,
   in graph order, are matched to the network's ``Conv2d`` modules in call order (shapes
   checked one by one); the ``BatchNormalization`` nodes the exporter kept (those after a
   pooling or sum) are matched to the remaining BatchNorm modules by name.
3. A folded BatchNorm cannot be split back into ``W`` and ``gamma / sigma``: the folded
   convolution gets ``W'`` and its BatchNorm is rebuilt so that it computes ``x + b'`` in
   eval mode yet normalises with sensible statistics in training mode. With ``m, v`` the
   per-channel mean and variance of ``conv(x; W')`` over calibration frames::

       running_mean = m, running_var = v, weight = sqrt(v + eps), bias = m + b'
       eval:  weight * (y - m) / sqrt(v + eps) + bias = y + b'          (exact)
       train: the same with batch statistics, close to (m, v) on similar frames

The result is checked against ONNX Runtime on the calibration frames (label agreement and
largest logit difference; an int8 model differs by its activation rounding). ONNX Runtime
runs the graph's own arithmetic there (``reference_arithmetic``), not the fused integer
kernels, whose results depend on the CPU (saturating on x86 without VNNI): the check then
measures the weights, not the CPU (up to float rounding).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from torch import nn

from harborsight.errors import InputError
from harborsight.perception.classes import CLASS_NAMES
from harborsight.perception.export import METADATA_KEY
from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import NETWORKS, create_network
from harborsight.perception.onnx_segmenter import OnnxSegmenter
from harborsight.training.checkpoint import AUX_STATE_PREFIX, CURRENT_NETWORK_OPTIONS

#: Labels of the recovered float model must agree with the ONNX model's on at least this
#: share of calibration pixels, or the recovery is refused. A gross check: the shipped int8
#: model and its recovered float weights agree on 99.9 % of simulator pixels, but only on
#: 78-98 % of a real photo's, where the model hesitates between classes and int8 rounding
#: tips many pixels.
MIN_LABEL_AGREEMENT = 0.9


@dataclass
class RecoveredModel:
    model: SegmentationModel                 # eval mode, with fresh auxiliary heads
    network: str
    network_options: dict
    label_agreement: float                   # recovered torch labels vs ONNX Runtime labels
    max_abs_logit_difference: float
    folded_batchnorms: int
    calibration_frames: int


def _metadata(proto: onnx.ModelProto, path: Path) -> dict:
    for entry in proto.metadata_props:
        if entry.key == METADATA_KEY:
            try:
                return json.loads(entry.value)
            except ValueError:
                break
    raise InputError(path, f"metadata.{METADATA_KEY}", "missing or not JSON: only models "
                     "written by `harborsight export` can be fine-tuned")


def _weights(graph: onnx.GraphProto) -> dict[str, np.ndarray]:
    """Every constant tensor by name: initialisers, DequantizeLinear outputs of initialisers
    (dequantised to float32), and Identity outputs of either (the exporter shares equal
    initialisers, e.g. the statistics of two BatchNorms with the same input, that way)."""
    values = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    for node in graph.node:
        if node.op_type == "Identity" and node.input[0] in values:
            values[node.output[0]] = values[node.input[0]]
        if node.op_type != "DequantizeLinear" or node.input[0] not in values:
            continue
        q = values[node.input[0]].astype(np.float32)
        scale = values[node.input[1]].astype(np.float32)
        zero = (values[node.input[2]].astype(np.float32) if len(node.input) > 2 and node.input[2]
                else np.zeros_like(scale))
        axis = next((a.i for a in node.attribute if a.name == "axis"), 1)
        if scale.ndim == 1 and scale.size > 1:
            shape = [1] * q.ndim
            shape[axis] = -1
            scale, zero = scale.reshape(shape), zero.reshape(shape)
        values[node.output[0]] = (q - zero) * scale
    return values


def _call_order(model: SegmentationModel, height: int, width: int) -> list[tuple[str, nn.Module, bool]]:
    """``(name, module, follows_conv)`` for every Conv2d and BatchNorm2d in the order the
    eval-mode forward pass calls them; ``follows_conv`` marks a BatchNorm whose input is
    the output of a convolution (the ones the exporter folds)."""
    order: list[tuple[str, nn.Module, bool]] = []
    conv_outputs: set[int] = set()
    hooks = []

    def hook(name):
        def record(module, inputs, output):
            if isinstance(module, nn.Conv2d):
                conv_outputs.add(id(output))
                order.append((name, module, False))
            else:
                order.append((name, module, id(inputs[0]) in conv_outputs))
        return record

    for name, module in model.named_modules():
        if isinstance(module, (nn.Conv2d, nn.BatchNorm2d)):
            hooks.append(module.register_forward_hook(hook(name)))
    kept_alive = []  # outputs must stay alive so that id() is not reused within the pass

    def keep(module, inputs, output):
        kept_alive.append(output)
    hooks += [m.register_forward_hook(keep) for m in model.modules()
              if isinstance(m, (nn.Conv2d, nn.BatchNorm2d))]
    try:
        with torch.no_grad():
            model.eval()(torch.zeros(1, height, width, 3, dtype=torch.uint8))
    finally:
        for h in hooks:
            h.remove()
    return order


def _module_path(node_name: str) -> str:
    """The module a node of the torch exporter belongs to, from its scope name:
    ``/model/network/stage2/stage2.0/skip/skip.0/Conv`` -> ``network.stage2.0.skip.0`` (each
    scope segment repeats its parent's name, ``stage2`` -> ``stage2.0``; ``model`` is the
    export wrapper's attribute)."""
    path: list[str] = []
    for segment in node_name.strip("/").split("/")[1:-1]:
        if path and segment.startswith(path[-1] + "."):
            path[-1] = segment
        else:
            path.append(segment)
    return ".".join(path)


def _match_convs(order, conv_nodes, path: Path) -> list[tuple[str, nn.Conv2d, onnx.NodeProto]]:
    """Each convolution the network calls with its ONNX ``Conv`` node, by scope name."""
    convs = {name: module for name, module, _ in order if isinstance(module, nn.Conv2d)}
    by_module = {_module_path(node.name): node for node in conv_nodes}
    if len(by_module) != len(conv_nodes) or set(by_module) != set(convs):
        missing = sorted(set(convs) - set(by_module))[:3]
        extra = sorted(set(by_module) - set(convs))[:3]
        raise InputError(path, "graph", f"its {len(conv_nodes)} Conv nodes do not match the "
                         f"network's {len(convs)} convolutions (no node for {missing}, no "
                         f"module for {extra}): not this network's export")
    return [(name, module, by_module[name]) for name, module in convs.items()]


def _load_into(model: SegmentationModel, graph: onnx.GraphProto, path: Path,
               height: int, width: int) -> list[tuple[nn.BatchNorm2d, np.ndarray]]:
    """Copy the graph's weights into ``model``; returns each folded BatchNorm with the
    folded bias ``b'`` it must add (set up for calibration: identity plus bias)."""
    values = _weights(graph)
    conv_nodes = [n for n in graph.node if n.op_type == "Conv"]
    bn_nodes = {n.input[1]: n for n in graph.node if n.op_type == "BatchNormalization"}
    order = _call_order(model, height, width)
    convs = _match_convs(order, conv_nodes, path)
    folded_by_conv = {}
    for k, (_, module, follows) in enumerate(order):
        if isinstance(module, nn.BatchNorm2d) and follows:
            folded_by_conv[order[k - 1][0]] = module
    folded: list[tuple[nn.BatchNorm2d, np.ndarray]] = []
    for name, conv, node in convs:
        weight = values.get(node.input[1])
        bias = values.get(node.input[2]) if len(node.input) > 2 and node.input[2] else None
        if weight is None or tuple(weight.shape) != tuple(conv.weight.shape):
            raise InputError(path, f"graph.Conv[{node.name}]", f"weight shape "
                             f"{None if weight is None else tuple(weight.shape)} does not fit "
                             f"{name} {tuple(conv.weight.shape)}")
        conv.weight.data.copy_(torch.from_numpy(np.array(weight, np.float32)))
        batchnorm = folded_by_conv.get(name)
        if batchnorm is not None:
            b = bias if bias is not None else np.zeros(weight.shape[0], np.float32)
            if conv.bias is not None:  # folded into b' with the BatchNorm
                conv.bias.data.zero_()
            batchnorm.reset_running_stats()
            batchnorm.weight.data.fill_(1.0)
            batchnorm.bias.data.zero_()
            batchnorm.running_var.fill_(1.0 - batchnorm.eps)
            folded.append((batchnorm, b.astype(np.float32)))
        elif conv.bias is not None:
            if bias is None:
                raise InputError(path, f"graph.Conv[{node.name}]", f"no bias for {name}")
            conv.bias.data.copy_(torch.from_numpy(np.array(bias, np.float32)))
        elif bias is not None and np.abs(bias).max() > 0:
            raise InputError(path, f"graph.Conv[{node.name}]", f"{name} has no bias and no "
                             "BatchNorm after it, but the graph gives it one")
    for name, module, follows in order:
        if not isinstance(module, nn.BatchNorm2d) or follows:
            continue
        node = bn_nodes.get(f"model.{name}.weight_DequantizeLinear_Output") or bn_nodes.get(
            f"model.{name}.weight")
        if node is None:
            raise InputError(path, "graph", f"no BatchNormalization node for {name}")
        scale, shift, mean, var = (values[node.input[i]] for i in range(1, 5))
        for tensor, value in ((module.weight.data, scale), (module.bias.data, shift),
                              (module.running_mean, mean), (module.running_var, var)):
            tensor.copy_(torch.from_numpy(np.array(value, np.float32)))
    return folded


def _calibrate_folded(model: SegmentationModel, folded: list[tuple[nn.BatchNorm2d, np.ndarray]],
                      images_bgr: list[np.ndarray]) -> None:
    """Give each folded BatchNorm the statistics of its input (step 3 of the module doc).
    The BatchNorms are identities with bias while the statistics are gathered, so the
    network already computes the exported function and one pass gathers all of them."""
    sums = {id(bn): [0.0, 0.0, 0] for bn, _ in folded}
    targets = {id(bn): bn for bn, _ in folded}

    def gather(module, inputs):
        x = inputs[0].double()
        entry = sums[id(module)]
        entry[0] = entry[0] + x.sum(dim=(0, 2, 3))
        entry[1] = entry[1] + (x * x).sum(dim=(0, 2, 3))
        entry[2] += x.shape[0] * x.shape[2] * x.shape[3]

    for bn, b in folded:
        bn.bias.data.copy_(torch.from_numpy(b))
    hooks = [bn.register_forward_pre_hook(gather) for bn in targets.values()]
    try:
        with torch.no_grad():
            for image in images_bgr:
                model.eval()(torch.from_numpy(image[None]))
    finally:
        for h in hooks:
            h.remove()
    for bn, b in folded:
        total, squares, count = sums[id(bn)]
        mean = total / count
        var = (squares / count - mean * mean).clamp_min(1e-6)
        bn.running_mean.copy_(mean.float())
        bn.running_var.copy_(var.float())
        bn.weight.data.copy_(torch.sqrt(var + bn.eps).float())
        bn.bias.data.copy_((mean + torch.from_numpy(b).double()).float())


def recover_model(onnx_path: str | Path, images_bgr: list[np.ndarray],
                  expect_network: str | None = None) -> RecoveredModel:
    """The float :class:`SegmentationModel` an exported ONNX model came from (module doc),
    its folded BatchNorms calibrated and the result checked on ``images_bgr`` (uint8 BGR
    frames like the training data; a few dozen are plenty)."""
    path = Path(onnx_path)
    if not images_bgr:
        raise InputError(path, None, "recovering weights needs calibration frames")
    try:
        proto = onnx.load(str(path))
    except Exception as exc:  # protobuf raises several types for a foreign file
        raise InputError(path, None, f"not a loadable ONNX model: {exc}") from None
    info = _metadata(proto, path)
    network = info.get("network")
    if network not in NETWORKS:
        raise InputError(path, f"metadata.{METADATA_KEY}.network", f"unknown network {network!r}")
    if expect_network is not None and network != expect_network:
        raise InputError(path, f"metadata.{METADATA_KEY}.network", f"holds {network}, but this "
                         f"run trains {expect_network}")
    if list(info.get("classes", CLASS_NAMES)) != list(CLASS_NAMES):
        raise InputError(path, f"metadata.{METADATA_KEY}.classes", f"{info.get('classes')} are "
                         f"not the classes this version trains ({list(CLASS_NAMES)})")
    height, width = int(info["input_height"]), int(info["input_width"])
    reference = OnnxSegmenter(path, threads=2, reference_arithmetic=True)
    attempts = []
    # Exports record the network options since 2026-11-24. DDRNet's options changed maths,
    # not weights, and the default model predates the record: its graph tells which one it
    # is only through its outputs, so both are tried and the better one is kept.
    recorded = info.get("network_options")
    candidates = [dict(recorded) if isinstance(recorded, dict) else
                  CURRENT_NETWORK_OPTIONS.get(network, {})]
    if recorded is None and network.startswith("ddrnet"):
        candidates.append({**candidates[0], "layer5_relu": False})
    for options in candidates:
        model = SegmentationModel(create_network(network, len(CLASS_NAMES), aux_heads=True,
                                                 **options))
        folded = _load_into(model, proto.graph, path, height, width)
        _calibrate_folded(model, folded, images_bgr)
        agree, worst = _compare(model, reference, images_bgr)
        attempts.append((agree, worst, options, model, len(folded)))
    agree, worst, options, model, n_folded = max(attempts, key=lambda a: a[0])
    if agree < MIN_LABEL_AGREEMENT:
        raise InputError(path, "graph", f"recovered weights reproduce only {agree:.1%} of the "
                         f"model's labels (need {MIN_LABEL_AGREEMENT:.0%})")
    return RecoveredModel(model.eval(), network, dict(options), agree, worst, n_folded,
                          len(images_bgr))


def _compare(model: SegmentationModel, reference: OnnxSegmenter,
             images_bgr: list[np.ndarray]) -> tuple[float, float]:
    """(share of pixels with equal labels, largest |logit difference|) torch vs ONNX, at
    the ONNX model's input size (frames are resized the way the segmenter resizes them)."""
    same = total = 0
    worst = 0.0
    model.eval()
    with torch.no_grad():
        for image in images_bgr:
            fitted = reference.fit(image)
            theirs = reference.logits(fitted)
            ours = model(torch.from_numpy(fitted[None]))[0].numpy()
            worst = max(worst, float(np.abs(ours - theirs).max()))
            same += int((ours.argmax(0) == theirs.argmax(0)).sum())
            total += ours.shape[1] * ours.shape[2]
    return same / total, worst


def checkpoint_state(recovered: RecoveredModel) -> dict[str, torch.Tensor]:
    """The recovered model's state dict without the (untrained) auxiliary heads."""
    return {k: v for k, v in recovered.model.state_dict().items()
            if not k.startswith(AUX_STATE_PREFIX)}
