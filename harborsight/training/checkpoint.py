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
    network_options  constructor options of the network (e.g. {"layer5_relu": true} for
                  DDRNet); absent in checkpoints written before 2026-11-23, which get
                  :data:`LEGACY_NETWORK_OPTIONS`
    averaged_from only in averaged checkpoints: each source's {path, iteration, command, weight}
    grafted_from  only in grafted checkpoints: {base, donor: {path, iteration, command},
                  layers, tensors} (the base's own provenance fields are kept)
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import torch

from harborsight.errors import InputError
from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import NETWORKS, create_network, layer_groups

CHECKPOINT_FORMAT = "harborsight.checkpoint/1"
#: State-dict prefix of the training-only auxiliary heads.
AUX_STATE_PREFIX = "network.aux_heads."
#: What a checkpoint without ``network_options`` was trained as: DDRNet's one-unit
#: bottleneck stages ended without their ReLU until 2026-11-23 (same weights, other maths).
LEGACY_NETWORK_OPTIONS = {"ddrnet23_slim": {"layer5_relu": False}, "ddrnet23": {"layer5_relu": False}}
#: The options a new run records.
CURRENT_NETWORK_OPTIONS = {"ddrnet23_slim": {"layer5_relu": True}, "ddrnet23": {"layer5_relu": True}}


def network_options(payload: dict) -> dict:
    """The constructor options the checkpoint's network was trained with."""
    options = payload.get("network_options")
    if options is None:
        options = LEGACY_NETWORK_OPTIONS.get(payload["network"], {})
    return dict(options)


def save_checkpoint(path: str | Path, payload: dict) -> Path:
    """``torch.save`` to a temporary file beside ``path``, flush it to disk (fsync), then
    rename over it (atomic on POSIX), so neither a crash mid-write nor a power loss just after
    the rename leaves a truncated checkpoint."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as stream:
            torch.save(payload, stream)
            stream.flush()
            os.fsync(stream.fileno())
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


def model_from_checkpoint(checkpoint: dict | str | Path, aux_heads: bool = False,
                          source: str | Path | None = None) -> SegmentationModel:
    """The checkpoint's :class:`SegmentationModel` in eval mode, on the CPU; without its
    training-only auxiliary heads unless ``aux_heads``. ``source`` names the file in errors
    when ``checkpoint`` is an already loaded dict."""
    if not isinstance(checkpoint, dict):
        source = checkpoint
    payload = checkpoint if isinstance(checkpoint, dict) else load_checkpoint(checkpoint)
    try:
        model = SegmentationModel(create_network(payload["network"], int(payload["num_classes"]),
                                                 aux_heads=aux_heads, **network_options(payload)))
        state = payload["model"]
        if not aux_heads:
            state = {k: v for k, v in state.items() if not k.startswith(AUX_STATE_PREFIX)}
        missing, unexpected = model.load_state_dict(state, strict=False)
    except KeyError as exc:
        raise InputError(source, str(exc.args[0]), "missing from the checkpoint") from None
    except (RuntimeError, TypeError) as exc:
        detail = next((line.strip() for line in str(exc).splitlines() if "size mismatch" in line),
                      str(exc).splitlines()[0])
        raise InputError(source, "model", f"weights do not fit {payload['network']}: "
                         f"{detail[:300]}") from None
    if missing or unexpected:
        raise InputError(source, "model", f"weights do not fit {payload['network']}: "
                         f"{len(missing)} tensor(s) missing (e.g. {missing[:2]}), "
                         f"{len(unexpected)} unexpected (e.g. {unexpected[:2]})")
    return model.eval()


def _check_same_network(paths: list[str | Path], payloads: list[dict]) -> None:
    """Refuse checkpoints that are not one network with the same tensors as the last one:
    network, classes, options and every tensor's name and shape, naming the file and field."""
    reference, reference_path = payloads[-1], Path(paths[-1])
    for path, payload in zip(paths, payloads, strict=True):
        for field in ("network", "num_classes", "class_names"):
            if payload.get(field) != reference.get(field):
                raise InputError(path, field, f"{payload.get(field)!r} differs from "
                                 f"{reference.get(field)!r} in {reference_path}")
        if network_options(payload) != network_options(reference):
            raise InputError(path, "network_options", f"{network_options(payload)} differs from "
                             f"{network_options(reference)} in {reference_path}")
        state, ref_state = payload["model"], reference["model"]
        if state.keys() != ref_state.keys():
            raise InputError(path, "model", f"its tensors differ from those of {reference_path}")
        for key, tensor in state.items():
            if tensor.shape != ref_state[key].shape:
                raise InputError(path, f"model.{key}", f"shape {tuple(tensor.shape)} differs "
                                 f"from {tuple(ref_state[key].shape)} in {reference_path}")


def graft_checkpoints(base: str | Path, donor: str | Path, groups: list[str]) -> dict:
    """A checkpoint with ``base``'s weights except those of the layer ``groups`` (top-level
    modules of the network, :func:`harborsight.perception.networks.layer_groups`), which
    come from ``donor``: every
    tensor under ``network.<group>.``, BatchNorm statistics included.

    For two checkpoints of one lineage, e.g. a fine-tune (base) and the model it started
    from (donor): keeping the donor's early layers undoes what the fine-tune changed in the
    low-level features while keeping what it learned deeper. Fine-tuning some blocks only
    adapts better to some kinds of distribution shift than tuning all (Lee et al. 2022,
    "Surgical fine-tuning improves adaptation to distribution shifts"); this does the same
    after the fact. The groups' BatchNorm statistics come with them; the base's deeper
    BatchNorm statistics were gathered on the base's own early features, so score the
    result before using it (for the default model they were kept: docs/results.md). The
    result has no optimiser state; ``grafted_from`` records both sources and the groups."""
    if not groups:
        raise InputError(None, "layers", "name at least one layer group to take from the donor")
    paths = [Path(donor), Path(base)]
    donor_payload, base_payload = (load_checkpoint(p) for p in paths)
    _check_same_network(paths, [donor_payload, base_payload])
    available = layer_groups(create_network(base_payload["network"], base_payload["num_classes"],
                                            aux_heads=True, **network_options(base_payload)))
    unknown = [g for g in groups if g not in available]
    if unknown:
        raise InputError(None, "layers", f"unknown layer group(s) {', '.join(unknown)}; "
                         f"{base_payload['network']} has: {', '.join(available)}")
    prefixes = tuple(f"network.{g}." for g in groups)
    state = {key: (donor_payload["model"][key] if key.startswith(prefixes) else tensor).clone()
             for key, tensor in base_payload["model"].items()}

    def source(path: Path, payload: dict) -> dict:
        return {"path": str(path), "iteration": payload.get("iteration"),
                "command": payload.get("command")}

    return {**base_payload, "network_options": network_options(base_payload), "model": state,
            "optimizer": None, "scaler": None, "rng": None, "val_miou": None,
            "best_val_miou": None,
            "grafted_from": {"base": source(paths[1], base_payload),
                             "donor": source(paths[0], donor_payload), "layers": list(groups),
                             "tensors": sum(key.startswith(prefixes) for key in state)}}


def average_checkpoints(paths: list[str | Path], weights: list[float] | None = None) -> dict:
    """A checkpoint whose weights are the weighted mean of several checkpoints' ("model soup",
    Wortsman et al. 2022): ``theta = sum_i w_i theta_i / sum_i w_i`` for every floating-point
    tensor, BatchNorm running means and variances included; integer tensors (BatchNorm step
    counts) come from the last checkpoint.

    Averaging only makes sense for checkpoints of one lineage (one fine-tuned from the other,
    or both from a common start), where the weights lie in one basin; it is checked that the
    network, classes and tensor shapes agree. The result has no optimiser state (it cannot be
    resumed, only exported, evaluated or used with ``--init-from``); ``averaged_from`` records
    each source's path, iteration, command and weight."""
    if len(paths) < 2:
        raise InputError(None, "checkpoint", "averaging needs at least two checkpoints")
    weights = [1.0] * len(paths) if weights is None else [float(w) for w in weights]
    if len(weights) != len(paths):
        raise InputError(None, "weight", f"{len(weights)} weight(s) for {len(paths)} checkpoints")
    if (any(not math.isfinite(w) or w < 0 for w in weights) or sum(weights) <= 0
            or not math.isfinite(sum(weights))):
        raise InputError(None, "weight", "weights must be finite and non-negative, with a "
                         "positive, finite sum")
    payloads = [load_checkpoint(p) for p in paths]
    reference = payloads[-1]
    _check_same_network(paths, payloads)
    total = sum(weights)
    averaged = {}
    for key, ref_tensor in reference["model"].items():
        if ref_tensor.is_floating_point():
            mean = sum(w / total * p["model"][key].double() for w, p in zip(weights, payloads,
                                                                            strict=True))
            averaged[key] = mean.to(ref_tensor.dtype)
        else:
            averaged[key] = ref_tensor.clone()
    sources = [{"path": str(path), "iteration": p.get("iteration"), "command": p.get("command"),
                "weight": w / total} for path, p, w in zip(paths, payloads, weights, strict=True)]
    return {**reference, "network_options": network_options(reference),
            "model": averaged, "optimizer": None, "scaler": None, "rng": None,
            "val_miou": None, "best_val_miou": None, "averaged_from": sources}
