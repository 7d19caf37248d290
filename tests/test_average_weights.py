"""Weight averaging ("model soup") gives the weighted mean of every float tensor and refuses
checkpoints that cannot be averaged, naming the file and field."""

import pytest
import torch
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.perception.model import SegmentationModel
from harborsight.perception.networks import create_network
from harborsight.training.checkpoint import (
    CHECKPOINT_FORMAT,
    average_checkpoints,
    load_checkpoint,
    model_from_checkpoint,
    save_checkpoint,
)

runner = CliRunner()


def write_checkpoint(path, network="ddrnet23_slim", seed=0, iteration=10):
    torch.manual_seed(seed)
    model = SegmentationModel(create_network(network, 3, aux_heads=True))
    for module in model.modules():  # distinct running statistics per checkpoint
        if isinstance(module, torch.nn.BatchNorm2d):
            module.running_mean.uniform_(-1, 1)
            module.running_var.uniform_(0.5, 2)
            module.num_batches_tracked.fill_(iteration)
    return save_checkpoint(path, {
        "format": CHECKPOINT_FORMAT, "network": network, "num_classes": 3,
        "class_names": ["water", "ship", "obstacle"], "iteration": iteration,
        "model": model.state_dict(), "optimizer": {"state": {}}, "scaler": None, "rng": None,
        "config": {}, "command": f"harborsight train # {seed}", "frame_hw": [360, 640],
        "val_miou": 0.5, "best_val_miou": 0.5, "init_from": None})


def test_weighted_mean_of_every_float_tensor(tmp_path):
    a = write_checkpoint(tmp_path / "a.pt", seed=1, iteration=10)
    b = write_checkpoint(tmp_path / "b.pt", seed=2, iteration=20)
    state_a, state_b = load_checkpoint(a)["model"], load_checkpoint(b)["model"]
    averaged = average_checkpoints([a, b], [1.0, 3.0])
    floats = [k for k, v in state_a.items() if v.is_floating_point()]
    assert any("running_var" in k for k in floats) and any(".weight" in k for k in floats)
    for key in floats:
        expected = 0.25 * state_a[key] + 0.75 * state_b[key]
        torch.testing.assert_close(averaged["model"][key], expected, rtol=0, atol=1e-6)
    counts = [k for k in state_a if k.endswith("num_batches_tracked")]
    assert counts and all(int(averaged["model"][k]) == 20 for k in counts)
    assert averaged["optimizer"] is None and averaged["val_miou"] is None
    assert [s["weight"] for s in averaged["averaged_from"]] == [0.25, 0.75]
    assert [s["iteration"] for s in averaged["averaged_from"]] == [10, 20]


def test_cli_writes_a_checkpoint_that_loads_as_a_model(tmp_path):
    a = write_checkpoint(tmp_path / "a.pt", seed=1)
    b = write_checkpoint(tmp_path / "b.pt", seed=2)
    out = tmp_path / "soup" / "last.pt"
    result = runner.invoke(app, ["average-weights", "--checkpoint", str(a), "--checkpoint", str(b),
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    payload = load_checkpoint(out)
    assert payload["command"].startswith(f"harborsight average-weights --checkpoint {a}")
    model = model_from_checkpoint(payload)
    state_a, state_b = load_checkpoint(a)["model"], load_checkpoint(b)["model"]
    for key, value in model.state_dict().items():  # the inference graph holds the mean
        if value.is_floating_point():
            torch.testing.assert_close(value, 0.5 * state_a[key] + 0.5 * state_b[key],
                                       rtol=0, atol=1e-6)
    with torch.no_grad():
        logits = model(torch.zeros(1, 64, 96, 3, dtype=torch.uint8))
    assert logits.shape[-2:] == (64, 96)


def test_refuses_what_cannot_be_averaged(tmp_path):
    a = write_checkpoint(tmp_path / "a.pt")
    other = write_checkpoint(tmp_path / "other.pt", network="bisenetv2")
    with pytest.raises(InputError, match=r"other.pt: network: 'bisenetv2' differs"):
        average_checkpoints([a, other, a])
    with pytest.raises(InputError, match="at least two"):
        average_checkpoints([a])
    with pytest.raises(InputError, match=r"weight: 1 weight\(s\) for 2 checkpoints"):
        average_checkpoints([a, a], [1.0])
    with pytest.raises(InputError, match="weight: weights must be finite"):
        average_checkpoints([a, a], [1e308, 1e308])      # their sum overflows: all shares 0
    result = runner.invoke(app, ["average-weights", "--checkpoint", str(a), "--checkpoint",
                                 str(tmp_path / "missing.pt"), "--out", str(tmp_path / "x.pt")])
    assert result.exit_code == 2 and "missing.pt" in result.output
    assert "checkpoint file not found" in result.output and not (tmp_path / "x.pt").exists()


def test_ddrnet_one_unit_stages_end_in_their_relu():
    """ydhongHIT/DDRNet's _make_layer marks no_relu only on the last of two or more blocks,
    so layer5 and layer5_ (one bottleneck each) end in a ReLU; stages of two do not."""
    network = create_network("ddrnet23_slim", 3)
    assert isinstance(network.low5[0].act, torch.nn.ReLU)
    assert isinstance(network.high5[0].act, torch.nn.ReLU)
    assert isinstance(network.high4[-1].act, torch.nn.Identity)
    legacy = create_network("ddrnet23_slim", 3, layer5_relu=False)
    assert isinstance(legacy.low5[0].act, torch.nn.Identity)


def test_checkpoints_rebuild_the_network_they_were_trained_as(tmp_path):
    """A checkpoint from before network_options existed was trained without layer5's ReLU
    and is rebuilt so; one that records its options gets them."""
    old = write_checkpoint(tmp_path / "old.pt")
    assert isinstance(model_from_checkpoint(old).network.low5[0].act, torch.nn.Identity)
    payload = load_checkpoint(old)
    payload["network_options"] = {"layer5_relu": True}
    new = save_checkpoint(tmp_path / "new.pt", payload)
    assert isinstance(model_from_checkpoint(new).network.low5[0].act, torch.nn.ReLU)
    with pytest.raises(InputError, match="network_options"):
        average_checkpoints([old, new])


def test_weights_of_another_network_name_the_file(tmp_path):
    path = write_checkpoint(tmp_path / "x.pt")
    payload = load_checkpoint(path)
    payload["network"] = "bisenetv2"
    save_checkpoint(path, payload)
    with pytest.raises(InputError, match=r"x.pt: model: weights do not fit bisenetv2"):
        model_from_checkpoint(path)
    del payload["num_classes"]
    save_checkpoint(path, payload)
    with pytest.raises(InputError, match=r"x.pt: num_classes: missing"):
        model_from_checkpoint(path)


def test_resume_keeps_a_better_best_checkpoint(tmp_path):
    from harborsight.training.loop import _best_so_far

    best = write_checkpoint(tmp_path / "best.pt")  # best_val_miou 0.5
    assert _best_so_far(0.4, best) == 0.5
    assert _best_so_far(None, best) == 0.5
    assert _best_so_far(0.6, best) == 0.6
    assert _best_so_far(0.4, tmp_path / "none.pt") == 0.4
