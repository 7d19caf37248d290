"""Mixed training: dataset sampling weights (--data DIR:W) and a separate validation set."""

import json
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from harborsight.cli.training import parse_weighted_data
from harborsight.errors import InputError
from harborsight.training.augment import AugmentConfig
from harborsight.training.config import TrainConfig
from harborsight.training.dataset import SegmentationFrames
from harborsight.training.samples import TrainingSamples


def make_dataset(root: Path, n: int, value: int, val: int = 1) -> Path:
    """n frames of 8x8 whose image and labels are filled with ``value`` (labels: value % 3);
    the last ``val`` of them in the val split."""
    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    split = {}
    for k in range(n):
        stem = f"f{k}"
        cv2.imwrite(str(root / "images" / f"{stem}.png"), np.full((8, 8, 3), value, np.uint8))
        cv2.imwrite(str(root / "labels" / f"{stem}.png"), np.full((8, 8), value % 3, np.uint8))
        split[stem] = "train" if k < n - val else "val"
    (root / "dataset.json").write_text(json.dumps({"split": split}))
    return root


def test_weights_set_each_datasets_share_whatever_its_size(tmp_path):
    big = make_dataset(tmp_path / "big", 41, 10)      # 40 training frames
    small = make_dataset(tmp_path / "small", 3, 200)  # 2 training frames
    frames = SegmentationFrames([big, small], ["train"])
    samples = TrainingSamples(frames, seed=3, augmentation=AugmentConfig.geometric_only((8, 8)),
                              data_weights=[0.25, 0.75])
    drawn = Counter(frames.records[samples.frame_index(n)].dataset_dir.name for n in range(4000))
    assert abs(drawn["small"] / 4000 - 0.75) < 0.03
    # a pure function of (seed, n): the same sample number gives the same frame
    assert [samples.frame_index(n) for n in (5, 77, 5)] == [samples.frame_index(5),
                                                            samples.frame_index(77),
                                                            samples.frame_index(5)]
    # both of the small set's frames are drawn, never a val frame
    small_stems = {frames.records[samples.frame_index(n)].stem for n in range(200)
                   if frames.records[samples.frame_index(n)].dataset_dir.name == "small"}
    assert small_stems == {"f0", "f1"}
    # without weights, frames are drawn equally often: the small set gets 2/42
    plain = TrainingSamples(frames, seed=3, augmentation=AugmentConfig.geometric_only((8, 8)))
    share = sum(frames.records[plain.frame_index(n)].dataset_dir.name == "small"
                for n in range(4200)) / 4200
    assert abs(share - 2 / 42) < 0.005


def test_a_zero_weight_dataset_is_never_drawn(tmp_path):
    a = make_dataset(tmp_path / "a", 3, 10)
    b = make_dataset(tmp_path / "b", 3, 20)
    frames = SegmentationFrames([a, b], ["train"])
    samples = TrainingSamples(frames, 0, AugmentConfig.geometric_only((8, 8)), data_weights=[0, 1])
    assert {frames.records[samples.frame_index(n)].dataset_dir.name for n in range(300)} == {"b"}
    image, labels, _ = samples[0]
    assert (image == 20).all() and (labels == 20 % 3).all()


def test_weighted_data_options_parse(tmp_path):
    plain = make_dataset(tmp_path / "plain", 2, 1)
    odd = make_dataset(tmp_path / "x:2", 2, 1)   # a folder whose name ends like a weight
    assert parse_weighted_data([plain]) == ([str(plain)], None)
    assert parse_weighted_data([Path(f"{plain}:0.8"), Path(f"{odd}:0.2")]) == (
        [str(plain), str(odd)], [0.8, 0.2])
    assert parse_weighted_data([odd]) == ([str(odd)], None)
    assert parse_weighted_data([Path(f"{plain}:3"), odd]) == ([str(plain), str(odd)], [3.0, 1.0])


@pytest.mark.parametrize("weights, message", [([1.0], "1 weight"), ([0.0, 0.0], "positive sum"),
                                              ([-1.0, 2.0], "positive sum")])
def test_bad_weights_are_refused(tmp_path, weights, message):
    with pytest.raises(InputError, match=message):
        TrainConfig(model="ddrnet23_slim", data_dirs=["a", "b"], out_dir=str(tmp_path),
                    data_weights=weights)


def test_validation_can_use_other_folders(tmp_path):
    from harborsight.training.loop import train as run_training

    sim = make_dataset(tmp_path / "sim", 3, 30)
    real = make_dataset(tmp_path / "real", 4, 60)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[str(sim), str(real)],
                         data_weights=[0.5, 0.5], val_dirs=[str(real)], out_dir=str(tmp_path / "run"),
                         iterations=2, batch_size=2, crop_hw=(8, 8), val_every=2, device="cpu",
                         checkpoint_every=2, num_workers=0, threads=1)
    run_training(config, show_progress=False)
    log = [json.loads(line) for line in (tmp_path / "run" / "train_log.jsonl").read_text().splitlines()]
    val = [entry for entry in log if entry.get("kind") == "val"]
    assert val and val[-1]["pixels"] == 64           # the real set's one 8x8 val frame only
    assert "--val-data" in config.command_line() and f"{sim}:0.5" in config.command_line()


def test_several_validation_sets_count_equally(tmp_path):
    """Two val sets of very different sizes: best.pt is picked on the mean of their mIoUs,
    not on pooled pixels (where the larger set would decide alone); both are logged."""
    from harborsight.training.loop import train as run_training

    big = make_dataset(tmp_path / "big", 6, 30, val=2)
    small = make_dataset(tmp_path / "small", 4, 60)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[str(big), str(small)],
                         val_dirs=[str(big), str(small)], out_dir=str(tmp_path / "run"),
                         iterations=2, batch_size=2, crop_hw=(8, 8), val_every=2, device="cpu",
                         checkpoint_every=2, num_workers=0, threads=1)
    run_training(config, show_progress=False)
    log = [json.loads(line) for line in (tmp_path / "run" / "train_log.jsonl").read_text().splitlines()]
    [val] = [entry for entry in log if entry.get("kind") == "val"]
    per_set = val["per_dataset"]
    assert set(per_set) == {str(big), str(small)}
    mean = (per_set[str(big)]["miou"] + per_set[str(small)]["miou"]) / 2
    assert val["miou"] == pytest.approx(mean) and val["selection"] == "mean of per-dataset mIoU"
    assert val["pixels"] == 64 * 2 + 64                  # pooled: big's two val frames, small's one
    assert "pooled_miou" in val


def test_a_training_folder_without_val_frames_is_left_out_of_validation(tmp_path):
    """Default validation (every --data folder): a folder with no val split (an imported
    real set with train frames only) is passed over, not an error."""
    from harborsight.training.loop import train as run_training

    with_val = make_dataset(tmp_path / "a", 4, 30)
    train_only = make_dataset(tmp_path / "b", 4, 60, val=0)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[str(with_val), str(train_only)],
                         out_dir=str(tmp_path / "run"), iterations=2, batch_size=2, crop_hw=(8, 8),
                         val_every=2, device="cpu", checkpoint_every=2, num_workers=0, threads=1)
    run_training(config, show_progress=False)
    log = [json.loads(line) for line in (tmp_path / "run" / "train_log.jsonl").read_text().splitlines()]
    [val] = [entry for entry in log if entry.get("kind") == "val"]
    assert "per_dataset" not in val and val["pixels"] == 64


@pytest.mark.parametrize("freeze", [False, True])
def test_freeze_batchnorm_keeps_the_running_statistics(tmp_path, freeze):
    """--freeze-batchnorm: the BatchNorm running statistics are what the run began with
    (here the fresh 0 / 1), while the weights, BatchNorm scales among them, still learn;
    without it the statistics follow the training batches."""
    from harborsight.training.checkpoint import load_checkpoint
    from harborsight.training.loop import train as run_training

    data = make_dataset(tmp_path / "d", 4, 90)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[str(data)], out_dir=str(tmp_path / "run"),
                         iterations=2, batch_size=2, crop_hw=(8, 8), val_every=2, device="cpu",
                         checkpoint_every=2, num_workers=0, threads=1, freeze_batchnorm=freeze)
    run_training(config, show_progress=False)
    state = load_checkpoint(tmp_path / "run" / "last.pt")["model"]
    means = [v for k, v in state.items() if k.endswith("running_mean")]
    scales = [v for k, v in state.items() if k.endswith(".weight") and v.ndim == 1]
    assert means and all((m == 0).all() for m in means) == freeze
    assert any((s != 1).any() for s in scales)               # BatchNorm scales learnt either way
    assert ("--freeze-batchnorm" in config.command_line()) == freeze


def test_frozen_layer_groups_keep_their_weights_and_statistics(tmp_path):
    """--freeze-layers: the named groups end as they began (weights and BatchNorm statistics),
    the rest learns; the command line records it, and a resume keeps it."""
    from harborsight.training.checkpoint import load_checkpoint
    from harborsight.training.loop import train as run_training

    data = make_dataset(tmp_path / "d", 4, 90)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[str(data)], out_dir=str(tmp_path / "run"),
                         iterations=2, batch_size=2, crop_hw=(8, 8), val_every=0, device="cpu",
                         checkpoint_every=1, num_workers=0, threads=1,
                         freeze_layers=("stem", "stage1"))
    run_training(config, show_progress=False)
    first = load_checkpoint(tmp_path / "run" / "last.pt")
    assert first["iteration"] == 2
    start = TrainConfig(**{**first["config"], "iterations": 1, "out_dir": str(tmp_path / "one")})
    run_training(start, show_progress=False)    # the same seed: the weights after one step
    one = load_checkpoint(tmp_path / "one" / "last.pt")["model"]
    frozen = [k for k in one if k.startswith(("network.stem.", "network.stage1."))]
    learning = [k for k in one if k.startswith("network.stage2.") and k.endswith("weight")]
    assert frozen and learning
    for key in frozen:      # as initialised (the seed's), after one step and after two
        assert torch.equal(one[key], first["model"][key]), key
    assert any(not torch.equal(one[k], first["model"][k]) for k in learning)
    assert "--freeze-layers stem,stage1" in config.command_line()
    assert tuple(first["config"]["freeze_layers"]) == ("stem", "stage1")


@pytest.mark.parametrize(("layers", "message"), [
    (("stem", "trunk"), r"unknown layer group\(s\) trunk; ddrnet23_slim has: stem, stage1"),
    ((), r"unknown layer group\(s\) \(none given\)"),
    (("stem", "aux_heads"), "aux_heads are training-only heads"),
])
def test_unknown_frozen_layer_groups_are_refused(tmp_path, layers, message):
    with pytest.raises(InputError, match=f"freeze_layers: {message}"):
        TrainConfig(model="ddrnet23_slim", data_dirs=[str(tmp_path)], out_dir=str(tmp_path / "r"),
                    freeze_layers=layers)
