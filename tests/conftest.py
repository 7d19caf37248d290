"""Session-wide fixtures: a tiny schematic dataset and a briefly trained run on it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.helpers import write_schematic_dataset

#: 128x72 frames: 4 train, 2 val, 2 test.
TINY_SPLITS = ["train", "train", "val", "test", "train", "train", "val", "test"]


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Read-only: copy it before breaking anything."""
    root = tmp_path_factory.mktemp("tiny") / "dataset"
    write_schematic_dataset(root, TINY_SPLITS)
    return root


@pytest.fixture(scope="session")
def trained_run(tmp_path_factory, tiny_dataset) -> Path:
    """A run folder (last.pt, best.pt, train_log.jsonl) after 4 iterations of DDRNet-23-slim."""
    from harborsight.training.loop import TrainConfig, train

    out = tmp_path_factory.mktemp("run") / "run"
    train(TrainConfig(model="ddrnet23_slim", data_dirs=[str(tiny_dataset)], out_dir=str(out),
                      iterations=4, batch_size=2, crop_hw=(64, 64), val_every=2,
                      checkpoint_every=2, num_workers=0, threads=1), show_progress=False)
    return out


@pytest.fixture(scope="session")
def untrained_model(tmp_path_factory) -> Path:
    """An untrained DDRNet-23-slim exported at 72x128 with a sidecar."""
    import torch

    from harborsight.perception.export import export_onnx
    from harborsight.perception.model import SegmentationModel
    from harborsight.perception.networks import create_network

    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "default.onnx"
    model = SegmentationModel(create_network("ddrnet23_slim", 3, aux_heads=False)).eval()
    export_onnx(model, path, 72, 128, {"network": "ddrnet23_slim"})
    path.with_suffix(".json").write_text(json.dumps({
        "schema": "harborsight.model/1", "classes": {"0": "water", "1": "ship", "2": "obstacle"}}))
    return path


@pytest.fixture(scope="session")
def nadir_scene(tmp_path_factory):
    """A classic tiny simulator scene (open water) seen straight down from 40 m: a camera and
    a vessel to place hand-made objects around (view culling, wakes)."""
    from harborsight.sim.dataset import SimulationConfig, plan_frame, prepare_vessels
    from harborsight.vessel.spec import load_vessel_spec

    config = SimulationConfig(seed=3, preset="tiny", vessel_pool=1, altitudes_m=(40.0,),
                              max_tilt_deg=0.0, scenario="open")
    out = tmp_path_factory.mktemp("nadir-vessels")
    vessels = {n: load_vessel_spec(p) for n, p in prepare_vessels(out, config).items()}
    return plan_frame(config, 0, vessels)
