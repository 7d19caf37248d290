"""The training loop learns, validates, checkpoints, resumes exactly, and refuses bad runs."""

import json
import math
import shlex
import shutil

import pytest
import torch
from typer.testing import CliRunner

from harborsight.cli import app
from harborsight.errors import InputError
from harborsight.training.checkpoint import load_checkpoint, model_from_checkpoint
from harborsight.training.loop import TrainConfig, learning_rate, train

runner = CliRunner()


def read_log(run_dir, kind="train"):
    lines = [json.loads(line) for line in (run_dir / "train_log.jsonl").read_text().splitlines()]
    return [line for line in lines if line["kind"] == kind]


@pytest.fixture
def two_frame_dataset(tiny_dataset, tmp_path):
    """The tiny dataset with only two training frames: batch 2 sees both every step."""
    root = tmp_path / "two"
    shutil.copytree(tiny_dataset, root)
    meta = json.loads((root / "dataset.json").read_text())
    train_stems = [s for s, split in meta["split"].items() if split == "train"]
    for stem in train_stems[2:]:
        meta["split"][stem] = "unused"
    (root / "dataset.json").write_text(json.dumps(meta))
    return root


def test_overfits_one_batch_and_validates(two_frame_dataset, tmp_path):
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[two_frame_dataset], out_dir=tmp_path / "run",
                         iterations=25, batch_size=2, crop_hw=(72, 128), augment=False,
                         val_every=25, checkpoint_every=10, num_workers=0, seed=3, threads=1)
    result = train(config, show_progress=False)
    losses = result.losses
    assert len(losses) == 25 and result.iteration == 25
    assert sum(losses[-5:]) / 5 < 0.5 * sum(losses[:5]) / 5, losses
    log = read_log(tmp_path / "run")
    assert [line["iteration"] for line in log] == list(range(1, 26))
    assert [line["loss"] for line in log] == losses
    assert log[0]["lr"] == pytest.approx(0.01) and log[-1]["lr"] < 0.01
    assert all(line["keep_fraction"] == 1.0 for line in log)  # before iteration 1000
    (val,) = read_log(tmp_path / "run", "val")
    assert val["iteration"] == 25 and 0.0 <= val["miou"] <= 1.0
    last, best = load_checkpoint(result.last_checkpoint), load_checkpoint(result.best_checkpoint)
    assert last["iteration"] == best["iteration"] == 25
    assert best["val_miou"] == pytest.approx(val["miou"]) and best["optimizer"] is None
    assert last["frame_hw"] == [72, 128] and last["config"]["crop_hw"] == [72, 128]
    model = model_from_checkpoint(best)
    assert model.network.aux_heads is None and not model.training


def test_resume_repeats_an_uninterrupted_run(tiny_dataset, tmp_path):
    # BiSeNetV2's dropout makes the result depend on the restored torch RNG as well
    def config(out):
        return TrainConfig(model="bisenetv2", data_dirs=[tiny_dataset], out_dir=out, iterations=6,
                           batch_size=2, crop_hw=(64, 64), val_every=0, checkpoint_every=100,
                           num_workers=0, seed=11, threads=1)

    threads = torch.get_num_threads()
    whole = train(config(tmp_path / "whole"), show_progress=False)
    assert torch.get_num_threads() == threads  # restored after the call
    first = train(config(tmp_path / "split"), until_iteration=3, show_progress=False)
    assert first.iteration == 3 and load_checkpoint(first.last_checkpoint)["iteration"] == 3
    with (tmp_path / "split" / "train_log.jsonl").open("a") as log:  # a crash after the checkpoint
        log.write(json.dumps({"iteration": 4, "kind": "train", "loss": -1.0}) + "\n")
        log.write('{"iteration": 5, "kind": "tr')                    # killed mid-line
    with pytest.raises(InputError, match="resume it"):
        train(config(tmp_path / "split"), show_progress=False)
    second = train(config(tmp_path / "split"), resume=True, show_progress=False)
    assert first.losses + second.losses == whole.losses
    assert [line["loss"] for line in read_log(tmp_path / "split")] == whole.losses
    a = load_checkpoint(tmp_path / "whole" / "last.pt")["model"]
    b = load_checkpoint(tmp_path / "split" / "last.pt")["model"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    changed = config(tmp_path / "split")
    changed.lr = 0.02
    with pytest.raises(InputError, match=r"changed lr: 0.01 -> 0.02"):
        train(changed, resume=True, show_progress=False)


def test_resume_refuses_a_changed_frame_set(tiny_dataset, tmp_path):
    """The sampling order depends on the frames: a grown dataset is a new run, not a resume."""
    data = tmp_path / "data"
    shutil.copytree(tiny_dataset, data)
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[data], out_dir=tmp_path / "run",
                         iterations=4, batch_size=2, crop_hw=(64, 64), val_every=0,
                         checkpoint_every=2, num_workers=0, threads=1)
    train(config, until_iteration=2, show_progress=False)
    meta = json.loads((data / "dataset.json").read_text())
    meta["split"][next(s for s, split in meta["split"].items() if split == "val")] = "train"
    (data / "dataset.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"last.pt: train_frames: the training frames changed "
                                         r"since the run began \(4 then, 5 readable now\)"):
        train(config, resume=True, show_progress=False)


def test_unreadable_frames_are_left_out_up_front(tiny_dataset, tmp_path, capsys):
    """A broken train label and a broken val image cost those frames, not the run."""
    data = tmp_path / "data"
    shutil.copytree(tiny_dataset, data)
    meta = json.loads((data / "dataset.json").read_text())
    train_stem = next(s for s, split in meta["split"].items() if split == "train")
    val_stem = next(s for s, split in meta["split"].items() if split == "val")
    (data / "labels" / f"{train_stem}.png").write_bytes(b"not a png")
    (data / "images" / f"{val_stem}.png").unlink()
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[data], out_dir=tmp_path / "run",
                         iterations=2, batch_size=2, crop_hw=(64, 64), val_every=2,
                         checkpoint_every=2, num_workers=0, threads=1)
    result = train(config, show_progress=False)
    assert result.iteration == 2 and result.val_miou is not None
    last = load_checkpoint(result.last_checkpoint)
    assert last["train_frames"]["count"] == 3
    assert [p.split("/")[-2:] for p in last["skipped_frames"]] == [
        ["labels", f"{train_stem}.png"], ["images", f"{val_stem}.png"]]


def test_warm_start_begins_from_the_checkpoint_weights(two_frame_dataset, tmp_path):
    def config(out, **changes):
        return TrainConfig(**{"model": "ddrnet23_slim", "data_dirs": [two_frame_dataset],
                              "out_dir": out, "iterations": 3, "batch_size": 2,
                              "crop_hw": (48, 64), "augment": False, "val_every": 0,
                              "num_workers": 0, "seed": 2, "threads": 1, **changes})

    source = train(config(tmp_path / "source"), show_progress=False)
    start = load_checkpoint(source.last_checkpoint)["model"]
    # lr 1e-12: one step moves a weight by lr·|grad|, under 1e-6 even where a 48x64 crop leaves
    # DDRNet's 1/64 branch one pixel, and BatchNorm over two such values has huge gradients;
    # two random initialisations differ by far more than 1e-3
    warm = train(config(tmp_path / "warm", iterations=1, lr=1e-12,
                        init_from=source.last_checkpoint), show_progress=False)
    cold = train(config(tmp_path / "cold", iterations=1, lr=1e-12), show_progress=False)
    warm_state = load_checkpoint(warm.last_checkpoint)
    conv = [k for k, v in start.items() if k.endswith("conv.weight") or v.ndim == 4]
    assert conv and all(torch.allclose(warm_state["model"][k], start[k], rtol=0, atol=1e-5)
                        for k in conv)
    cold_state = load_checkpoint(cold.last_checkpoint)["model"]
    assert not all(torch.allclose(cold_state[k], start[k], atol=1e-3) for k in conv)
    assert warm_state["iteration"] == 1 and read_log(tmp_path / "warm")[0]["lr"] == 1e-12
    assert warm_state["init_from"]["iteration"] == 3
    assert warm_state["init_from"]["path"] == str(source.last_checkpoint)
    assert f"--init-from {source.last_checkpoint}" in warm_state["command"]
    with pytest.raises(InputError, match=r"source/last.pt: network: holds ddrnet23_slim, but this "
                       r"run trains bisenetv2"):
        train(config(tmp_path / "other", model="bisenetv2", init_from=source.last_checkpoint),
              show_progress=False)
    with pytest.raises(InputError, match="checkpoint file not found"):
        train(config(tmp_path / "none", init_from=tmp_path / "missing.pt"), show_progress=False)


def test_small_object_weighting_trains_and_needs_instance_masks(two_frame_dataset, tmp_path):
    def config(out, **changes):
        return TrainConfig(**{"model": "ddrnet23_slim", "data_dirs": [two_frame_dataset],
                              "out_dir": tmp_path / out, "iterations": 2, "batch_size": 2,
                              "crop_hw": (64, 64), "val_every": 0, "num_workers": 0,
                              "threads": 1, "seed": 1, **changes})

    plain = train(config("plain"), show_progress=False)
    weighted = train(config("weighted", small_object_weight=8.0, small_object_area_px=4000.0),
                     show_progress=False)
    assert len(weighted.losses) == 2 and all(math.isfinite(x) for x in weighted.losses)
    # same samples and initial weights: the first loss differs only by the pixel weights
    assert weighted.losses[0] > plain.losses[0]
    stored = load_checkpoint(weighted.last_checkpoint)
    assert stored["config"]["small_object_weight"] == 8.0
    assert "--small-object-weight 8.0 --small-object-area 4000.0" in stored["command"]
    shutil.rmtree(two_frame_dataset / "instances")
    with pytest.raises(InputError, match=r"instances/0000\d\d.png: instance mask not found"):
        train(config("missing", small_object_weight=8.0), show_progress=False)


@pytest.mark.parametrize("changes, message", [
    ({"batch_size": 1}, r"batch_size: must be at least 2.*BatchNorm"),
    ({"model": "resnet"}, r"model: unknown network 'resnet'"),
    ({"aux_weights": (1.0, 1.0)}, r"aux_weights: ddrnet23_slim has 1 auxiliary head"),
    ({"device": "tpu"}, r"device: expected auto, cpu or cuda"),
    ({"small_object_weight": 0.5}, r"small_object_weight: must be at least 1"),
    ({"small_object_area_px": 0.0}, r"small_object_area_px: must be positive"),
    ({"distill": 1.0}, r"distill: distils from the network the run starts from: give --init-from"),
    ({"distill": -0.5, "init_from": "a.pt"}, r"distill: must be a weight >= 0"),
    ({"distill": 1.0, "init_from": "a.pt", "distill_temperature": 0.0},
     r"distill_temperature: must be positive"),
    ({"distill": 1.0, "init_from": "a.pt", "distill_view": "sharp"},
     r"distill_view: must be one of augmented, clean, got 'sharp'"),
    ({"distill_view": "clean"}, r"distill_view: is what the teacher of --distill sees"),
])
def test_bad_configs_are_refused(tmp_path, changes, message):
    base = {"model": "ddrnet23_slim", "data_dirs": ["x"], "out_dir": str(tmp_path)}
    with pytest.raises(InputError, match=message):
        TrainConfig(**{**base, **changes})


def test_missing_validation_split_suggests_val_every_0(two_frame_dataset, tmp_path):
    meta = json.loads((two_frame_dataset / "dataset.json").read_text())
    meta["split"] = {s: ("train" if v == "train" else "test") for s, v in meta["split"].items()}
    (two_frame_dataset / "dataset.json").write_text(json.dumps(meta))
    config = TrainConfig(model="ddrnet23_slim", data_dirs=[two_frame_dataset], out_dir=tmp_path,
                         iterations=1, batch_size=2, num_workers=0)
    with pytest.raises(InputError, match=r"no frames in split\(s\) \['val'\].*--val-every 0"):
        train(config, show_progress=False)


def test_learning_rate_warmup_then_poly():
    config = TrainConfig(model="bisenetv2", data_dirs=["x"], out_dir="y", iterations=100,
                         warmup_iterations=10, warmup_ratio=0.1)
    assert learning_rate(config, 0) == pytest.approx(0.001)
    assert learning_rate(config, 5) == pytest.approx(0.01 * (1 - 0.05) ** 0.9 * 0.55)
    assert learning_rate(config, 10) == pytest.approx(0.01 * 0.9 ** 0.9)


def test_cli_train_records_a_command_that_reproduces_the_run(tiny_dataset, tmp_path):
    args = ["train", "--model", "ddrnet23_slim", "--data", str(tiny_dataset),
            "--out", str(tmp_path / "a"), "--iterations", "3", "--batch-size", "2", "--crop", "48x64",
            "--aux-weight", "0.5", "--val-every", "0", "--seed", "5", "--workers", "0",
            "--no-augment", "--threads", "1", "--no-progress"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "trained ddrnet23_slim to iteration 3" in result.output
    command = load_checkpoint(tmp_path / "a" / "last.pt")["command"]
    again = shlex.split(command.replace(str(tmp_path / "a"), str(tmp_path / "b")))
    assert again[:2] == ["harborsight", "train"] and "--no-augment" in again
    result = runner.invoke(app, [*again[1:], "--no-progress"])
    assert result.exit_code == 0, result.output
    assert read_log(tmp_path / "a") == [
        {**line, "elapsed_s": read_log(tmp_path / "a")[i]["elapsed_s"]}
        for i, line in enumerate(read_log(tmp_path / "b"))]
    result = runner.invoke(app, ["train", "--out", str(tmp_path / "a"), "--resume",
                                 "--iterations", "4", "--no-progress"])
    assert result.exit_code == 0, result.output
    assert len(read_log(tmp_path / "a")) == 4


def test_cli_train_errors_are_one_line(tmp_path):
    result = runner.invoke(app, ["train", "--out", str(tmp_path), "--model", "bisenetv2"])
    assert result.exit_code == 2 and "needs --model and --data" in result.output
    result = runner.invoke(app, ["train", "--out", str(tmp_path), "--resume"])
    assert result.exit_code == 2 and "last.pt: checkpoint file not found" in result.output


def test_colour_jitter_and_haze_are_checked_recorded_and_used(tiny_dataset, tmp_path, monkeypatch):
    """--colour-jitter sets the brightness, contrast and saturation ranges of the augmentation
    (refused outside [0, 1)), --haze the haze's probability (refused outside [0, 1]), and the
    run records both so that its command reproduces them."""
    with pytest.raises(InputError, match="colour_jitter: must be in"):
        TrainConfig(model="ddrnet23_slim", data_dirs=[tiny_dataset], out_dir=tmp_path / "x",
                    colour_jitter=1.0)
    with pytest.raises(InputError, match="haze: must be a probability"):
        TrainConfig(model="ddrnet23_slim", data_dirs=[tiny_dataset], out_dir=tmp_path / "x",
                    haze=1.5)
    args = ["train", "--model", "ddrnet23_slim", "--data", str(tiny_dataset),
            "--out", str(tmp_path / "a"), "--iterations", "1", "--batch-size", "2", "--crop", "48x64",
            "--val-every", "0", "--workers", "0", "--threads", "1", "--colour-jitter", "0.6",
            "--haze", "0.3", "--no-progress"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    checkpoint = load_checkpoint(tmp_path / "a" / "last.pt")
    assert checkpoint["config"]["colour_jitter"] == 0.6
    assert "--colour-jitter 0.6" in checkpoint["command"]
    assert checkpoint["config"]["haze"] == 0.3 and "--haze 0.3" in checkpoint["command"]
    from harborsight.training import loop
    built = []
    original = loop.TrainingSamples

    def spy(frames, seed, augmentation, *rest, **options):
        built.append(augmentation)
        return original(frames, seed, augmentation, *rest, **options)

    monkeypatch.setattr(loop, "TrainingSamples", spy)
    train(TrainConfig(model="ddrnet23_slim", data_dirs=[tiny_dataset], out_dir=tmp_path / "b",
                      iterations=1, batch_size=2, crop_hw=(48, 64), val_every=0, threads=1,
                      colour_jitter=0.6, haze=0.3), show_progress=False)
    assert (built[0].brightness, built[0].contrast, built[0].saturation) == (0.6, 0.6, 0.6)
    assert built[0].p_haze == 0.3


def test_distillation_starts_from_the_teacher_and_resumes_exactly(two_frame_dataset, tmp_path):
    """--distill keeps the network the run started from as a frozen teacher (start.pt) that
    normalises as the student does, so the distillation loss is zero at the first step and
    grows as the student moves; it changes the steps taken, is logged and recorded in the
    command, and a resumed run rebuilds the teacher and repeats an uninterrupted one. (That
    it pulls the student toward the teacher is checked on the loss itself, in
    test_training_blocks.py; what it does to a real fine-tune is in docs/results.md.)"""
    def config(out, **changes):
        return TrainConfig(**{"model": "ddrnet23_slim", "data_dirs": [two_frame_dataset],
                              "out_dir": out, "iterations": 4, "batch_size": 2,
                              "crop_hw": (48, 64), "augment": False, "val_every": 0,
                              "checkpoint_every": 100, "num_workers": 0, "seed": 4,
                              "threads": 1, **changes})

    source = train(config(tmp_path / "source", iterations=8), show_progress=False)
    tune = dict(init_from=source.last_checkpoint, lr=0.01, aux_weights=(0.0,))
    kd = dict(tune, distill=2.0, distill_temperature=3.0)
    held = train(config(tmp_path / "held", **kd), show_progress=False)
    free = train(config(tmp_path / "free", **tune), show_progress=False)
    teacher = load_checkpoint(tmp_path / "held" / "start.pt")
    start = load_checkpoint(source.last_checkpoint)["model"]
    assert all(torch.equal(teacher["model"][k], v) for k, v in start.items())
    log = read_log(tmp_path / "held")
    assert log[0]["loss_distill"] == pytest.approx(0.0, abs=1e-9)
    assert all(line["loss_distill"] > 0.0 for line in log[1:])
    assert all(line["loss"] == pytest.approx(line["loss_main"] + 2.0 * line["loss_distill"],
                                             rel=1e-5) for line in log)
    assert "loss_distill" not in read_log(tmp_path / "free")[0]
    assert held.losses[0] == free.losses[0] and held.losses[1:] != free.losses[1:]
    recorded = load_checkpoint(held.last_checkpoint)
    assert "--distill 2.0 --distill-temperature 3.0" in recorded["command"]
    assert recorded["config"]["distill"] == 2.0

    first = train(config(tmp_path / "split", **kd), until_iteration=2, show_progress=False)
    second = train(config(tmp_path / "split", **kd), resume=True, show_progress=False)
    assert first.losses + second.losses == held.losses


def test_a_teacher_on_the_clean_view_reads_the_sample_before_its_haze(two_frame_dataset, tmp_path):
    """--distill-view clean: the teacher sees the crop before haze and colour jitter, so at
    the first step (student = teacher) the distillation term is no longer zero on hazed
    samples, as it is when the teacher sees the student's own input; the run is recorded
    with its view and resumes exactly."""
    def config(out, **changes):
        return TrainConfig(**{"model": "ddrnet23_slim", "data_dirs": [two_frame_dataset],
                              "out_dir": out, "iterations": 3, "batch_size": 2,
                              "crop_hw": (48, 64), "haze": 1.0, "colour_jitter": 0.5,
                              "val_every": 0, "checkpoint_every": 100, "num_workers": 0,
                              "seed": 4, "threads": 1, **changes})

    source = train(config(tmp_path / "source", augment=False, haze=0.0, iterations=6),
                   show_progress=False)
    kd = dict(init_from=source.last_checkpoint, lr=0.01, aux_weights=(0.0,), distill=1.0)
    train(config(tmp_path / "same", **kd), show_progress=False)
    clean = train(config(tmp_path / "clean", distill_view="clean", **kd), show_progress=False)
    assert read_log(tmp_path / "same")[0]["loss_distill"] == pytest.approx(0.0, abs=1e-9)
    first = read_log(tmp_path / "clean")[0]
    assert first["loss_distill"] > 1e-4
    assert first["loss_main"] == pytest.approx(read_log(tmp_path / "same")[0]["loss_main"])
    assert "--distill-view clean" in load_checkpoint(clean.last_checkpoint)["command"]
    part = train(config(tmp_path / "split", distill_view="clean", **kd), until_iteration=1,
                 show_progress=False)
    rest = train(config(tmp_path / "split", distill_view="clean", **kd), resume=True,
                 show_progress=False)
    assert part.losses + rest.losses == clean.losses
