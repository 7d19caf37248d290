"""Weights recovered from an exported ONNX model reproduce it, in fp32 and int8, and a run can
warm-start from one (train --init-from model.onnx)."""

import copy
import json
import shutil

import numpy as np
import onnx
import pytest
import torch

from harborsight.errors import InputError
from harborsight.perception.classes import CLASS_NAMES
from harborsight.perception.export import METADATA_KEY, export_onnx
from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import create_network
from harborsight.perception.quantization import quantize_int8
from harborsight.training.checkpoint import average_checkpoints, load_checkpoint
from harborsight.training.dataset import SegmentationFrames
from harborsight.training.from_onnx import _module_path, recover_model
from harborsight.training.loop import TrainConfig, train


def _model_with_statistics(network="ddrnet23_slim", seed=0, **options) -> SegmentationModel:
    """A network whose BatchNorms are far from identities, so folding them matters."""
    torch.manual_seed(seed)
    model = SegmentationModel(create_network(network, 3, aux_heads=False, **options))
    for module in model.modules():
        if isinstance(module, torch.nn.BatchNorm2d):
            n = module.num_features
            module.running_mean.copy_(torch.randn(n) * 0.3)
            module.running_var.copy_(torch.rand(n) * 2 + 0.5)
            module.weight.data.copy_(torch.rand(n) + 0.5)
            module.bias.data.copy_(torch.randn(n) * 0.2)
    return model.eval()


def _images(n=4, seed=1):
    rng = np.random.default_rng(seed)
    images = []
    for _ in range(n):
        image = np.full((72, 128, 3), rng.integers(40, 200, 3), np.uint8)
        image[20:50, 30:90] = rng.integers(0, 255, 3)
        images.append(np.clip(image + rng.normal(0, 12, image.shape), 0, 255).astype(np.uint8))
    return images


def _export(model, path, network="ddrnet23_slim", **extra):
    return export_onnx(model, path, 72, 128, {"network": network, "classes": list(CLASS_NAMES),
                                              **extra})


@pytest.mark.parametrize("network", ["ddrnet23_slim", "bisenetv2"])
def test_fp32_export_is_recovered_exactly(tmp_path, network):
    model = _model_with_statistics(network)
    path = _export(model, tmp_path / "m.onnx", network)
    images = _images()
    recovered = recover_model(path, images)
    assert recovered.network == network and recovered.folded_batchnorms > 10
    assert recovered.label_agreement > 0.999
    with torch.no_grad():
        for image in images:
            batch = torch.from_numpy(image[None])
            expected = model(batch)
            got = recovered.model(batch)
            scale = float(expected.abs().max())
            assert float((got - expected).abs().max()) < 1e-3 * max(1.0, scale)


def test_recovered_batchnorms_normalise_like_the_originals_in_training_mode(tmp_path):
    """A folded BatchNorm is rebuilt from the statistics of its input. For a model whose
    running statistics are those of the calibration frames, training mode (batch statistics)
    then computes what the original computes in training mode: fine-tuning starts where the
    original would have."""
    torch.manual_seed(0)
    model = SegmentationModel(create_network("ddrnet23_slim", 3, aux_heads=False))
    images = _images(6)
    batch = torch.from_numpy(np.stack(images))
    for module in model.modules():
        if isinstance(module, torch.nn.BatchNorm2d):
            module.momentum = None  # cumulative average: one pass gives the batch's statistics
            module.weight.data.uniform_(0.5, 1.5)
            module.bias.data.normal_(0.0, 0.2)
    with torch.no_grad():
        model.train()(batch)
    for module in model.modules():
        if isinstance(module, torch.nn.BatchNorm2d):
            module.momentum = 0.1
    recovered = recover_model(_export(model.eval(), tmp_path / "m.onnx"), images).model
    # the same weights with the folded BatchNorms left as identities plus bias: what a
    # recovery without statistics would give
    naive = copy.deepcopy(recovered)
    for module in naive.modules():
        if isinstance(module, torch.nn.BatchNorm2d) and torch.allclose(
                module.weight, torch.sqrt(module.running_var + module.eps)):
            module.bias.data -= module.running_mean
            module.weight.data.fill_(1.0)
    with torch.no_grad():
        expected = model.train()(batch)
        got = recovered.train()(batch)[0]
        without_statistics = naive.train()(batch)[0]
    error = float((got - expected).abs().mean())
    # 72x128 frames leave DDRNet's deepest maps 2x2 pixels, where batch and running
    # statistics differ by a few per cent: close, not exact
    assert error < 0.15 * float(expected.std())
    assert error < 0.2 * float((without_statistics - expected).abs().mean())
    assert (got.argmax(1) == expected.argmax(1)).float().mean() > 0.9


def test_int8_export_is_recovered_and_old_ddrnet_options_are_found(tmp_path):
    """The default model predates recorded network options and ships as int8: both cases."""
    model = _model_with_statistics(layer5_relu=False)
    fp32 = _export(model, tmp_path / "m.onnx")
    int8 = quantize_int8(fp32, tmp_path / "m.int8.onnx", np.stack(_images(4, seed=5)))
    proto = onnx.load(str(int8))
    entry = proto.metadata_props.add()
    entry.key, entry.value = METADATA_KEY, json.dumps({"network": "ddrnet23_slim",
                                                       "input_height": 72, "input_width": 128})
    onnx.save(proto, str(int8))
    recovered = recover_model(int8, _images())
    assert recovered.network_options == {"layer5_relu": False}
    assert recovered.label_agreement > 0.95


def test_module_path_of_exporter_scopes():
    assert _module_path("/model/network/stage2/stage2.0/skip/skip.0/Conv") == "network.stage2.0.skip.0"
    assert _module_path("/model/network/dappm/refine.0/refine.0.2/Conv") == "network.dappm.refine.0.2"
    assert _module_path("/model/network/head/classify/classify.2/Conv") == "network.head.classify.2"


def test_foreign_or_mismatched_models_are_refused(tmp_path):
    model = _model_with_statistics()
    path = _export(model, tmp_path / "m.onnx")
    with pytest.raises(InputError, match="holds ddrnet23_slim, but this run trains fchardnet70"):
        recover_model(path, _images(), expect_network="fchardnet70")
    with pytest.raises(InputError, match="needs calibration frames"):
        recover_model(path, [])
    bare = tmp_path / "bare.onnx"
    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    onnx.save(proto, str(bare))
    with pytest.raises(InputError, match=r"bare.onnx: metadata.harborsight: missing"):
        recover_model(bare, _images())
    other = _export(_model_with_statistics("bisenetv2"), tmp_path / "other.onnx", "ddrnet23_slim")
    with pytest.raises(InputError, match=r"other.onnx: graph: .*Conv nodes do not match"):
        recover_model(other, _images())
    (tmp_path / "junk.onnx").write_bytes(b"not a model")
    with pytest.raises(InputError, match=r"junk.onnx: not a loadable ONNX model"):
        recover_model(tmp_path / "junk.onnx", _images())


def test_training_warm_starts_from_an_onnx_model(tiny_dataset, tmp_path):
    model = _model_with_statistics(layer5_relu=False)
    path = _export(model, tmp_path / "m.onnx", network_options={"layer5_relu": False})
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[tiny_dataset], out_dir=tmp_path / "run",
                         iterations=1, batch_size=2, crop_hw=(48, 64), augment=False,
                         val_every=0, num_workers=0, seed=2, threads=1, lr=1e-12,
                         init_from=path)
    result = train(config, show_progress=False)
    state = load_checkpoint(result.last_checkpoint)
    assert state["network_options"] == {"layer5_relu": False}
    assert state["init_from"]["path"] == str(path)
    assert state["init_from"]["onnx"]["label_agreement"] > 0.999
    assert f"--init-from {path}" in state["command"]
    # unfolded convolutions (those with their own bias) carry the exported weights unchanged
    original = model.state_dict()
    key = "network.head.classify.2.weight"
    assert torch.allclose(state["model"][key], original[key], atol=1e-5)


def test_an_onnx_warm_start_keeps_its_starting_weights_for_interpolation(tiny_dataset, tmp_path):
    """start.pt holds the recovered weights at iteration 0, so that average-weights can
    interpolate between them and the fine-tuned ones (WiSE-FT)."""
    model = _model_with_statistics(layer5_relu=False)
    path = _export(model, tmp_path / "m.onnx", network_options={"layer5_relu": False})
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[tiny_dataset], out_dir=tmp_path / "run",
                         iterations=2, batch_size=2, crop_hw=(48, 64), augment=False,
                         val_every=0, num_workers=0, seed=2, threads=1, lr=0.05,
                         init_from=path)
    result = train(config, show_progress=False)
    start = load_checkpoint(tmp_path / "run" / "start.pt")
    last = load_checkpoint(result.last_checkpoint)
    key = "network.head.classify.2.weight"
    assert start["iteration"] == 0 and last["iteration"] == 2
    assert torch.allclose(start["model"][key], model.state_dict()[key], atol=1e-5)
    assert not torch.allclose(last["model"][key], start["model"][key], atol=1e-5)
    halfway = average_checkpoints([tmp_path / "run" / "start.pt", result.last_checkpoint])
    assert torch.allclose(halfway["model"][key], (start["model"][key] + last["model"][key]) / 2)


def test_fit_large_stretches_only_larger_frames(tiny_dataset, tmp_path):
    root = tmp_path / "data"
    shutil.copytree(tiny_dataset, root)
    plain = SegmentationFrames([root], ["train"])
    fitted = SegmentationFrames([root], ["train"], fit_large_hw=(36, 64))
    kept = SegmentationFrames([root], ["train"], fit_large_hw=(72, 128))
    image, labels = plain[0]
    small_image, small_labels = fitted[0]
    assert image.shape == (72, 128, 3) and small_image.shape == (36, 64, 3)
    assert small_labels.shape == (36, 64) and set(np.unique(small_labels)) <= set(np.unique(labels))
    # each label from the source pixel under the target pixel's centre, as the image's area
    # average is centred (legacy nearest sampling took the pixel to its left and above)
    rows = np.floor((np.arange(36) + 0.5) * 72 / 36).astype(int)
    cols = np.floor((np.arange(64) + 0.5) * 128 / 64).astype(int)
    np.testing.assert_array_equal(small_labels, labels[np.ix_(rows, cols)])
    assert np.array_equal(kept[0][1], labels)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[root], out_dir=tmp_path / "run",
                         iterations=1, batch_size=2, crop_hw=(32, 32), fit_large_hw=(36, 64),
                         val_every=1, num_workers=0, threads=1)
    result = train(config, show_progress=False)
    assert "--fit-large 36x64" in load_checkpoint(result.last_checkpoint)["command"]
