"""Grafting takes the named layer groups' tensors from the donor and every other tensor from
the base, refuses what does not fit (naming the file and field), and the CLI writes a
checkpoint that exports like any other."""

import pytest
import torch
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.perception.networks import create_network, layer_groups
from harborsight.training.checkpoint import graft_checkpoints, load_checkpoint, model_from_checkpoint
from tests.test_average_weights import write_checkpoint

runner = CliRunner()


def test_named_groups_come_from_the_donor_the_rest_from_the_base(tmp_path):
    base = write_checkpoint(tmp_path / "base.pt", seed=1, iteration=30)
    donor = write_checkpoint(tmp_path / "donor.pt", seed=2, iteration=10)
    grafted = graft_checkpoints(base, donor, ["stem", "stage1"])
    base_state, donor_state = load_checkpoint(base)["model"], load_checkpoint(donor)["model"]
    from_donor = 0
    for key, tensor in grafted["model"].items():
        grafted_here = key.startswith(("network.stem.", "network.stage1."))
        from_donor += grafted_here
        expected = donor_state[key] if grafted_here else base_state[key]
        assert torch.equal(tensor, expected), key
        if tensor.dim() == 4 and key.startswith("network."):    # kernels differ by seed
            assert not torch.equal(base_state[key], donor_state[key]), key  # a real test
    assert from_donor == grafted["grafted_from"]["tensors"] > 0
    assert grafted["grafted_from"]["layers"] == ["stem", "stage1"]
    assert grafted["grafted_from"]["donor"]["iteration"] == 10
    assert grafted["iteration"] == 30 and grafted["optimizer"] is None
    assert grafted["val_miou"] is None


def test_layer_groups_are_the_networks_top_level_modules():
    groups = layer_groups(create_network("ddrnet23_slim", 3))
    assert groups[:3] == ["stem", "stage1", "stage2"]
    assert {"low3", "high3", "dappm", "head"} <= set(groups)


def test_refuses_what_cannot_be_grafted(tmp_path):
    a = write_checkpoint(tmp_path / "a.pt")
    other = write_checkpoint(tmp_path / "other.pt", network="bisenetv2")
    with pytest.raises(InputError, match=r"other.pt: network: 'bisenetv2' differs"):
        graft_checkpoints(a, other, ["stem"])
    with pytest.raises(InputError, match=r"layers: unknown layer group\(s\) stem2; "
                                         r"ddrnet23_slim has: stem, stage1"):
        graft_checkpoints(a, a, ["stem", "stem2"])
    with pytest.raises(InputError, match="layers: name at least one"):
        graft_checkpoints(a, a, [])


def test_cli_writes_a_checkpoint_that_loads_as_a_model(tmp_path):
    base = write_checkpoint(tmp_path / "base.pt", seed=1)
    donor = write_checkpoint(tmp_path / "donor.pt", seed=2)
    out = tmp_path / "graft" / "model.pt"
    result = runner.invoke(app, ["graft-weights", "--base", str(base), "--donor", str(donor),
                                 "--layers", "stem, stage1,stage2", "--out", str(out)])
    assert result.exit_code == 0, result.output
    payload = load_checkpoint(out)
    assert payload["command"] == (f"harborsight graft-weights --base {base} --donor {donor} "
                                  f"--layers stem,stage1,stage2 --out {out}")
    model = model_from_checkpoint(payload)
    donor_state = load_checkpoint(donor)["model"]
    stage2 = [k for k in model.state_dict() if k.startswith("network.stage2.")]
    assert stage2 and all(torch.equal(model.state_dict()[k], donor_state[k]) for k in stage2)
    with torch.no_grad():
        logits = model(torch.zeros(1, 64, 96, 3, dtype=torch.uint8))
    assert logits.shape[-2:] == (64, 96)
    bad = runner.invoke(app, ["graft-weights", "--base", str(base), "--donor", str(donor),
                              "--layers", "trunk", "--out", str(tmp_path / "x.pt")])
    assert bad.exit_code == 2 and "unknown layer group(s) trunk" in bad.output
    assert not (tmp_path / "x.pt").exists()
