"""A warm start: the weights a run begins from (a checkpoint of the same network, or an ONNX
model written by ``harborsight export`` whose weights are recovered), their network
options and their provenance."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.perception.classes import CLASS_NAMES, NUM_CLASSES
from harborsight.perception.model import SegmentationModel
from harborsight.training.checkpoint import (
    AUX_STATE_PREFIX,
    load_checkpoint,
    network_options,
)
from harborsight.training.config import TrainConfig
from harborsight.training.dataset import SegmentationFrames


@dataclasses.dataclass
class InitialWeights:
    """Where a warm start begins: the weights, the network options they were trained with,
    and their provenance (recorded in the new run's checkpoints as ``init_from``)."""
    state: dict
    options: dict
    provenance: dict


#: Training frames whose statistics rebuild the folded BatchNorms of an ONNX warm start.
ONNX_CALIBRATION_FRAMES = 32


def load_initial_weights(config: TrainConfig, train_frames: SegmentationFrames) -> InitialWeights:
    """The weights ``config.init_from`` names: a checkpoint of the same network and classes,
    or an ONNX model written by ``harborsight export`` (the shipped default model among
    them), whose weights are recovered with :mod:`harborsight.training.from_onnx` using a few
    training frames. Auxiliary heads the source lacks keep their fresh initialisation.
    Optimiser, schedule and sampling still start at iteration 0."""
    path = Path(config.init_from)
    if path.suffix.lower() == ".onnx":
        from harborsight.training.from_onnx import checkpoint_state, recover_model
        picks = np.rint(np.linspace(0, len(train_frames) - 1,
                                    min(len(train_frames), ONNX_CALIBRATION_FRAMES))).astype(int)
        recovered = recover_model(path, [train_frames[int(i)][0] for i in sorted(set(picks))],
                                  expect_network=config.model)
        return InitialWeights(checkpoint_state(recovered), recovered.network_options, {
            "path": str(path), "iteration": None, "command": None, "onnx": {
                "label_agreement": round(recovered.label_agreement, 5),
                "max_abs_logit_difference": round(recovered.max_abs_logit_difference, 4),
                "folded_batchnorms": recovered.folded_batchnorms,
                "calibration_frames": recovered.calibration_frames}})
    source = load_checkpoint(path)
    if source["network"] != config.model:
        raise InputError(path, "network", f"holds {source['network']}, but this run trains "
                         f"{config.model}")
    if int(source["num_classes"]) != NUM_CLASSES or list(source["class_names"]) != list(CLASS_NAMES):
        raise InputError(path, "class_names", f"holds classes {source['class_names']}, this run "
                         f"trains {list(CLASS_NAMES)}")
    return InitialWeights(source["model"], network_options(source), {
        "path": str(path), "iteration": int(source["iteration"]),
        "command": source.get("command")})


def apply_initial_weights(model: SegmentationModel, initial: InitialWeights, path: str) -> None:
    missing, unexpected = model.load_state_dict(initial.state, strict=False)
    wrong = [k for k in missing if not k.startswith(AUX_STATE_PREFIX)] + list(unexpected)
    if wrong:
        raise InputError(path, "model", f"weights do not fit this network: {wrong[:5]}")
