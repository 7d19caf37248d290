"""Checkpoint -> deployable ONNX model (+ optional int8 copy) and its JSON sidecar.

The sidecar ``<model>.json`` (schema ``harborsight.model/1``) records what a deployment needs
to trust the file: network, class map, fixed input size, parameter count, how it was trained
(command, seed, iteration), its validation mIoU, the largest |logit| difference between ONNX
Runtime and torch on check images, and for int8 the mIoU of the fp32 and int8 models on the
calibration data.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import onnx
import torch

from harborsight.errors import InputError
from harborsight.evaluation.segmentation import score_frames
from harborsight.perception.classes import CLASS_NAMES, IGNORE
from harborsight.perception.export import METADATA_KEY, export_onnx, onnx_max_abs_difference
from harborsight.perception.networks import inference_parameter_count
from harborsight.perception.onnx_segmenter import OnnxSegmenter
from harborsight.perception.quantization import (
    DEFAULT_CALIBRATION_PERCENTILE,
    check_calibration,
    quantize_int8,
)
from harborsight.training.checkpoint import load_checkpoint, model_from_checkpoint, network_options
from harborsight.training.dataset import SegmentationFrames

SIDECAR_SCHEMA = "harborsight.model/1"


def sidecar_path(model_path: str | Path) -> Path:
    """``model.onnx`` -> ``model.json``."""
    return Path(model_path).with_suffix(".json")


@dataclass
class ExportResult:
    onnx_path: Path
    sidecar_path: Path
    max_abs_difference: float
    max_abs_logit: float                           # scale of the logits on the check images
    int8_path: Path | None = None
    miou_fp32: float | None = None
    miou_int8: float | None = None
    int8_label_agreement: float | None = None     # share of pixels where both models agree
    sidecar: dict | None = None
    #: ``(path, reason)`` of calibration frames left out because they could not be read
    skipped_frames: list[tuple[str, str]] = field(default_factory=list)


def _evenly_spaced(n_items: int, n_pick: int) -> list[int]:
    if n_items <= n_pick:
        return list(range(n_items))
    return sorted(set(np.rint(np.linspace(0, n_items - 1, n_pick)).astype(int).tolist()))


def _fit(image: np.ndarray, height: int, width: int) -> np.ndarray:
    if image.shape[:2] == (height, width):
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def _finite(value: float) -> float | None:
    return value if np.isfinite(value) else None


def _copy_metadata(source: Path, target: Path) -> None:
    """Give the int8 model the fp32 model's ``harborsight`` metadata (quantisation drops it)."""
    value = next(p.value for p in onnx.load(str(source)).metadata_props if p.key == METADATA_KEY)
    proto = onnx.load(str(target))
    kept = [p for p in proto.metadata_props if p.key != METADATA_KEY]
    del proto.metadata_props[:]
    proto.metadata_props.extend(kept)
    entry = proto.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, value
    onnx.save(proto, str(target))


def export_checkpoint(
    checkpoint_path: str | Path, out_path: str | Path, height: int | None = None,
    width: int | None = None, int8: bool = False,
    calibration_dirs: Sequence[str | Path] | None = None,
    calibration_splits: Sequence[str] | None = None, calibration_frames: int = 16,
    calibration_method: str = "minmax", calibration_percentile: float = DEFAULT_CALIBRATION_PERCENTILE,
) -> ExportResult:
    """Export a checkpoint to ONNX at ``height`` x ``width`` (default: its training frames'
    size), check it against torch and write the sidecar; with ``int8`` also quantise, calibrated
    on up to ``calibration_frames`` evenly spaced frames of the calibration data (activation
    ranges by ``calibration_method``, one of
    :data:`~harborsight.perception.quantization.CALIBRATION_METHODS`), and compare fp32 and
    int8 mIoU on all of that data's selected frames.

    Every file is written in a scratch folder beside ``out_path`` and moved into place only
    when all of them are done, so a failure never leaves a new model beside an old sidecar."""
    checkpoint_path, out_path = Path(checkpoint_path), Path(out_path)
    check_calibration(calibration_method, calibration_percentile)
    if out_path.suffix.lower() != ".onnx":
        raise InputError(out_path, None, "the output model must end in .onnx")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".{out_path.stem}-export-", dir=out_path.parent))
    try:
        result = _export(checkpoint_path, scratch / out_path.name, height, width, int8,
                         calibration_dirs, calibration_splits, calibration_frames,
                         calibration_method, calibration_percentile)
        finals = {}
        for path in (result.onnx_path, result.int8_path, result.sidecar_path):
            if path is not None:
                finals[path] = out_path.parent / path.name
                os.replace(path, finals[path])
        result.onnx_path, result.sidecar_path = finals[result.onnx_path], finals[result.sidecar_path]
        if result.int8_path is not None:
            result.int8_path = finals[result.int8_path]
        return result
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _export(
    checkpoint_path: Path, out_path: Path, height: int | None, width: int | None, int8: bool,
    calibration_dirs: Sequence[str | Path] | None, calibration_splits: Sequence[str] | None,
    calibration_frames: int, calibration_method: str, calibration_percentile: float,
) -> ExportResult:
    if int8 and not calibration_dirs:
        raise InputError(None, "calibration_data", "int8 quantisation needs calibration frames "
                         "(--calibration-data DIR)")
    payload = load_checkpoint(checkpoint_path)
    model = model_from_checkpoint(payload, source=checkpoint_path)
    frame_hw = payload.get("frame_hw") or (360, 640)
    height, width = int(height or frame_hw[0]), int(width or frame_hw[1])
    config = payload.get("config", {})
    params = inference_parameter_count(model.network)
    metadata = {"network": payload["network"], "network_options": network_options(payload),
                "classes": list(CLASS_NAMES), "params": params,
                "iteration": payload.get("iteration"), "val_miou": payload.get("val_miou")}
    export_onnx(model, out_path, height, width, metadata)

    frames = SegmentationFrames(calibration_dirs, calibration_splits) if calibration_dirs else None
    skipped = frames.drop_unreadable() if frames is not None else []
    if frames is not None:
        check = np.stack([_fit(frames[i][0], height, width) for i in _evenly_spaced(len(frames), 4)])
    else:
        check = np.random.default_rng(0).integers(0, 256, (2, height, width, 3), dtype=np.uint8)
    with torch.no_grad():
        difference = onnx_max_abs_difference(model, out_path, check)
        scale = max(float(model(torch.from_numpy(img[None])).abs().max()) for img in check)
    result = ExportResult(out_path, sidecar_path(out_path), difference, scale,
                          skipped_frames=skipped)

    if int8 and frames is not None:
        result.int8_path = out_path.with_name(f"{out_path.stem}.int8.onnx")
        calibration = np.stack([_fit(frames[i][0], height, width)
                                for i in _evenly_spaced(len(frames), calibration_frames)])
        quiet = logging.getLogger()  # the quantiser warns per 1-D weight on the root logger
        level = quiet.level
        quiet.setLevel(logging.ERROR)
        try:
            quantize_int8(out_path, result.int8_path, calibration, calibration_method,
                          calibration_percentile)
        finally:
            quiet.setLevel(level)
        _copy_metadata(out_path, result.int8_path)
        # the int8 graph's own arithmetic, not this CPU's fused kernels (which saturate on
        # x86 without VNNI): the sidecar's int8 figures describe the model
        fp32 = OnnxSegmenter(out_path)
        quant = OnnxSegmenter(result.int8_path, reference_arithmetic=True)
        agree = [0, 0]

        def agreement(image: np.ndarray) -> np.ndarray:
            a, b = fp32.segment(image), quant.segment(image)
            agree[0] += int((a == b).sum())
            agree[1] += a.size
            return a

        result.miou_fp32 = _finite(score_frames(agreement, frames).miou)
        result.miou_int8 = _finite(score_frames(quant.segment, frames).miou)
        result.int8_label_agreement = agree[0] / agree[1]

    result.sidecar = {
        "schema": SIDECAR_SCHEMA,
        "onnx": out_path.name,
        "onnx_int8": result.int8_path.name if result.int8_path else None,
        "network": payload["network"],
        "classes": {str(i): name for i, name in enumerate(CLASS_NAMES)},
        "ignore_index": IGNORE,
        "input": {"height": height, "width": width, "format": "uint8 BGR (1, H, W, 3)"},
        "params": params,
        "training": {"checkpoint": str(checkpoint_path), "iteration": payload.get("iteration"),
                     "iterations": config.get("iterations"), "seed": config.get("seed"),
                     "command": payload.get("command"), "data": config.get("data_dirs")},
        "val_miou": payload.get("val_miou"),
        "best_val_miou": payload.get("best_val_miou"),
        "onnx_max_abs_difference": difference,
        "torch_max_abs_logit": scale,
        "int8": None if result.int8_path is None else {
            "calibration_frames": len(calibration), "evaluation_frames": len(frames),
            "calibration_method": calibration_method,
            "calibration_percentile": (calibration_percentile if calibration_method == "percentile"
                                       else None),
            "calibration_data": [str(d) for d in calibration_dirs],
            "miou_fp32": result.miou_fp32, "miou_int8": result.miou_int8,
            "label_agreement": result.int8_label_agreement,
            "int8_arithmetic": "reference",     # the graph as written (segment --exact-int8)
            "skipped_frames": [path for path, _ in skipped],
        },
    }
    result.sidecar_path.write_text(json.dumps(result.sidecar, indent=2) + "\n")
    return result
