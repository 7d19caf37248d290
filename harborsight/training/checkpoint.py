"""Training checkpoints: written atomically, loaded with clear errors, turned back into models.

A checkpoint is a ``torch.save`` dict (loadable with ``weights_only=True``)::

    format        "harborsight.checkpoint/1"
    network       registry name (harborsight.perception.networks.NETWORKS)
    num_classes, class_names
    iteration     optimiser steps completed
    model         SegmentationModel state dict (aux heads included)
    optimizer, scaler, rng   for an exact resume (None in best.pt)
    config        TrainConfig as a plain dict; command: an equivalent command line
    frame_hw      most common (height, width) of the training frames
    val_miou, best_val_miou   latest and best validation mIoU (None without validation)
    init_from     None, or the warm start's {path, iteration, command}
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from harborsight.errors import InputError
from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import NETWORKS, create_network

CHECKPOINT_FORMAT = "harborsight.checkpoint/1"
#: State-dict prefix of the training-only auxiliary heads.
AUX_STATE_PREFIX = "network.aux_heads."


def save_checkpoint(path: str | Path, payload: dict) -> Path:
    """``torch.save`` to a temporary file beside ``path``, then rename over it (atomic on
    POSIX), so a crash mid-write never leaves a truncated checkpoint."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        torch.save(payload, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> dict:
    """A checkpoint dict, checked for format and a known network."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "checkpoint file not found")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises several types for corrupt or foreign files
        raise InputError(path, None, f"not a loadable torch checkpoint: {exc}") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise InputError(path, "format", f"expected a {CHECKPOINT_FORMAT} checkpoint")
    if payload.get("network") not in NETWORKS:
        raise InputError(path, "network", f"unknown network {payload.get('network')!r}")
    return payload


def model_from_checkpoint(checkpoint: dict | str | Path, aux_heads: bool = False) -> SegmentationModel:
    """The checkpoint's :class:`SegmentationModel` in eval mode, on the CPU; without its
    training-only auxiliary heads unless ``aux_heads``."""
    payload = checkpoint if isinstance(checkpoint, dict) else load_checkpoint(checkpoint)
    model = SegmentationModel(create_network(payload["network"], int(payload["num_classes"]),
                                             aux_heads=aux_heads))
    state = payload["model"]
    if not aux_heads:
        state = {k: v for k, v in state.items() if not k.startswith(AUX_STATE_PREFIX)}
    model.load_state_dict(state)
    return model.eval()
