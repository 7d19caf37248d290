"""The training commands: ``models``, ``train``, ``average-weights``, ``graft-weights`` and
``export``."""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from harborsight.cli.app import (
    MAX_THREADS,
    app,
    console,
    err_console,
    fmt_number,
    need_torch,
    parse_crop,
    split_names,
)
from harborsight.errors import HarborsightError, InputError
from harborsight.files import prepare_output_file
from harborsight.perception.quantization import DEFAULT_CALIBRATION_PERCENTILE, check_calibration


@app.command()
def models(
    num_classes: Annotated[int, typer.Option(min=1, max=1000, help="Classes of the output layer.")] = 3,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """List the segmentation networks with their parameter counts and input size rule."""
    try:
        from harborsight.perception.networks import (
            NETWORKS,
            create_network,
            inference_parameter_count,
            parameter_count,
        )
    except ImportError as exc:
        err_console.print(f"error: the networks need torch (pip install -e '.[train]'): {exc}")
        raise typer.Exit(2) from None
    rows = []
    for name in NETWORKS:
        network = create_network(name, num_classes, aux_heads=True)
        stride = int(network.output_stride)
        rows.append({
            "name": name,
            "params": inference_parameter_count(network),
            "params_with_aux_heads": parameter_count(network),
            "output_stride": stride,
            "input_size_rule": f"any size; padded inside the model to multiples of {stride}",
        })
    if as_json:
        print(json.dumps(rows, indent=2))
        return
    table = Table(title=f"segmentation networks ({num_classes} classes)", title_justify="left")
    for column in ("network", "params (inference)", "with aux heads", "output stride"):
        table.add_column(column, justify="left" if column == "network" else "right")
    for row in rows:
        table.add_row(row["name"], f"{row['params']:,}", f"{row['params_with_aux_heads']:,}",
                      str(row["output_stride"]))
    console.print(table)
    console.print("input: any frame size; padded inside the model to a multiple of the stride")


def parse_weighted_data(entries: list[Path]) -> tuple[list[str], list[float] | None]:
    """``DIR`` or ``DIR:W`` entries -> folders and weights (None when no entry has one; an
    entry without one then weighs 1)."""
    folders, weights = [], []
    for entry in entries:
        text = str(entry)
        head, _, tail = text.rpartition(":")
        try:
            weight = float(tail) if head and not Path(text).is_dir() else None
        except ValueError:
            weight = None
        folders.append(head if weight is not None else text)
        weights.append(weight)
    if all(w is None for w in weights):
        return folders, None
    return folders, [1.0 if w is None else w for w in weights]


def parse_copy_paste(entries: list[str], data_dirs: list[str]) -> list[float]:
    """``DIR:P`` entries -> one probability per ``--data`` folder (0 where none is given)."""
    probabilities = [0.0] * len(data_dirs)
    for entry in entries:
        folder, _, tail = entry.rpartition(":")
        try:
            probability = float(tail)
        except ValueError:
            raise InputError(None, "copy_paste", f"expected DIR:P, got {entry!r}") from None
        matches = [k for k, d in enumerate(data_dirs) if Path(d) == Path(folder)]
        if not folder or not matches:
            raise InputError(None, "copy_paste", f"{folder or entry!r} is not one of the --data "
                             f"folders ({', '.join(data_dirs) or 'none'})")
        for k in matches:
            probabilities[k] = probability
    return probabilities


@app.command()
def train(
    out: Annotated[Path, typer.Option(help="Run folder: last.pt, best.pt, train_log.jsonl.")],
    model: Annotated[str | None, typer.Option(
        help="Network: bisenetv2, fchardnet70, ddrnet23_slim, ddrnet23 (see harborsight models).")
    ] = None,
    data: Annotated[list[Path] | None, typer.Option(
        help="Dataset folder (dataset.json, images/, labels/); repeat for several. DIR:W gives "
        "it sampling weight W (e.g. --data sim:0.8 --data real:0.2): each sample comes from a "
        "dataset with probability proportional to its weight, whatever its size; without "
        "weights every training frame is drawn equally often.")] = None,
    val_data: Annotated[list[Path] | None, typer.Option(
        help="Validate (and pick best.pt) on the val split of these folders only, e.g. the "
        "real frames of a mixed run (default: every --data folder that has a val split). With "
        "several, each is scored on its own and best.pt goes to the highest mean of their "
        "mIoUs, so that a small real set counts as much as a large simulator set.")] = None,
    resume: Annotated[bool, typer.Option(
        help="Continue the run in --out from last.pt exactly (other options may only change "
        "--iterations, --val-every, --checkpoint-every, --workers, --threads, --device).")
    ] = False,
    iterations: Annotated[int | None, typer.Option(min=1, help="Optimiser steps [10000].")] = None,
    batch_size: Annotated[int | None, typer.Option(help="Images per step, at least 2 [8].")] = None,
    crop: Annotated[str | None, typer.Option(
        help="Training crop HEIGHTxWIDTH in pixels, or N for NxN [360x360].")] = None,
    fit_large: Annotated[str | None, typer.Option(
        help="HEIGHTxWIDTH, e.g. 360x640 (the model input): frames larger than this are "
        "stretched to it before cropping and validation, smaller ones keep their scale; what "
        "`segment --mode auto` does, so a model trains at the scale it will see [off].")] = None,
    freeze_batchnorm: Annotated[bool | None, typer.Option(
        help="Keep every BatchNorm's running statistics as --init-from left them (BatchNorm "
        "layers in eval mode; their scale and shift still learn): a fine-tune on new data "
        "then does not shift the statistics the model's earlier data was normalised with "
        "[off].")] = None,
    copy_paste: Annotated[list[str] | None, typer.Option(
        help="DIR:P, repeatable: a training sample of --data folder DIR gets, with probability "
        "P, 1-3 of DIR's own training vessels pasted onto its open water (turned by 90 degree "
        "steps, never over a dock, a boat or an undecided pixel; the ring around each is "
        "ignore): more of a rare ship class, e.g. small boats on lake-shore photos. A folder "
        "keeps its own scale, so give it for folders whose frames share a GSD.")] = None,
    freeze_layers: Annotated[str | None, typer.Option(
        help="Comma-separated layer groups of the network (its top-level modules, e.g. "
        "stem,stage1,stage2 for DDRNet) that do not learn: no gradient, BatchNorm statistics "
        "kept. With --init-from, a fine-tune on real photos that leaves the first layers as "
        "they were keeps the simulator's low-level features (docs/results.md) [none].")] = None,
    lr: Annotated[float | None, typer.Option(help="Initial learning rate [0.01].")] = None,
    momentum: Annotated[float | None, typer.Option(help="SGD momentum [0.9].")] = None,
    weight_decay: Annotated[float | None, typer.Option(
        help="Weight decay on conv/linear weights [5e-4].")] = None,
    poly_power: Annotated[float | None, typer.Option(help="Poly LR exponent [0.9].")] = None,
    warmup: Annotated[int | None, typer.Option(help="Linear LR warm-up iterations [0].")] = None,
    warmup_ratio: Annotated[float | None, typer.Option(
        help="LR factor at the start of the warm-up [0.1].")] = None,
    aux_weight: Annotated[list[float] | None, typer.Option(
        help="Weight of each auxiliary head's loss, repeated per head [bisenetv2 1 1 1 1, "
        "ddrnet 0.4].")] = None,
    bootstrap_start: Annotated[int | None, typer.Option(
        help="Iteration where the bootstrapped CE starts dropping easy pixels [1000].")] = None,
    bootstrap_end: Annotated[int | None, typer.Option(
        help="Iteration where it reaches --bootstrap-fraction [9000].")] = None,
    bootstrap_fraction: Annotated[float | None, typer.Option(
        help="Share of the hardest pixels kept at the end [0.2].")] = None,
    small_object_weight: Annotated[float | None, typer.Option(
        help="Up-weight small objects' pixels by clip(sqrt(A_ref / area), 1, this); needs the "
        "datasets' instances/ masks; 1: off [1].")] = None,
    small_object_area: Annotated[float | None, typer.Option(
        help="A_ref of --small-object-weight, in pixels: objects this large keep weight 1 "
        "[1000].")] = None,
    augment: Annotated[bool | None, typer.Option(
        help="Mirror/flip/scale/colour/blur/noise/JPEG augmentation; off: random crop only.")
    ] = None,
    colour_jitter: Annotated[float | None, typer.Option(
        help="Colour augmentation strength j: brightness, contrast and saturation each scaled "
        "by a factor drawn in [1-j, 1+j] [0.25]; raise it when real frames differ in colour "
        "(pale or hazy orthophotos).")] = None,
    haze: Annotated[float | None, typer.Option(
        help="Probability of the haze augmentation (I·t + A·(1-t): transmission t in "
        "[0.45, 0.95], a bright near-grey airlight A), for hazy, washed-out real imagery; "
        "0: off [0].")] = None,
    distill: Annotated[float | None, typer.Option(
        help="With --init-from: weight λ of a distillation loss that keeps the main head's "
        "softened outputs near the starting network's on the pixels the starting network "
        "labels correctly (Learning without Forgetting), so that a fine-tune on real frames "
        "forgets less of the simulator; 0: off [0].")] = None,
    distill_temperature: Annotated[float | None, typer.Option(
        help="Softmax temperature T of --distill (loss scaled by T²) [2].")] = None,
    distill_view: Annotated[str | None, typer.Option(
        help="What the teacher of --distill sees: 'augmented' (the student's input) or "
        "'clean' (the same crop before haze, colour jitter, blur, noise and JPEG: the student "
        "learns to read through them as the teacher reads the clear view) [augmented].")
    ] = None,
    train_split: Annotated[str | None, typer.Option(help="Split to train on [train].")] = None,
    val_split: Annotated[str | None, typer.Option(help="Split to validate on [val].")] = None,
    val_every: Annotated[int | None, typer.Option(
        help="Validate (mIoU, best.pt) every N iterations; 0: never [1000].")] = None,
    checkpoint_every: Annotated[int | None, typer.Option(
        help="Write last.pt every N iterations [500].")] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of weights, sampling and augmentation [0].")
    ] = None,
    device: Annotated[str | None, typer.Option(help="auto, cpu or cuda[:N] [auto].")] = None,
    amp: Annotated[bool | None, typer.Option(help="fp16 autocast on CUDA [on].")] = None,
    workers: Annotated[int | None, typer.Option(
        help="DataLoader worker processes [CPU: 0, CUDA: min(8, cores - 1)].")] = None,
    threads: Annotated[int | None, typer.Option(
        min=1, max=MAX_THREADS,
        help="torch CPU threads; on a shared machine fewer threads than cores can be much "
        "faster [torch's default].")] = None,
    init_from: Annotated[Path | None, typer.Option(
        help="Warm start: begin from this checkpoint's weights, or from an ONNX model written "
        "by `harborsight export` (the shipped default among them; its weights are recovered "
        "and checked against it); same network; optimiser and schedule start afresh. E.g. to "
        "fine-tune the default model on real frames.")] = None,
    progress: Annotated[bool, typer.Option(help="Show the progress bar.")] = True,
) -> None:
    """Train a segmentation network on simulator-layout datasets (needs torch)."""
    need_torch()
    from harborsight.training.checkpoint import load_checkpoint
    from harborsight.training.config import TrainConfig
    from harborsight.training.loop import LAST
    from harborsight.training.loop import train as run_training

    try:
        given = {"iterations": iterations, "batch_size": batch_size, "lr": lr,
                 "momentum": momentum, "weight_decay": weight_decay, "poly_power": poly_power,
                 "warmup_iterations": warmup, "warmup_ratio": warmup_ratio,
                 "crop_hw": parse_crop(crop) if crop else None,
                 "fit_large_hw": parse_crop(fit_large, "fit_large") if fit_large else None,
                 "freeze_batchnorm": freeze_batchnorm,
                 "freeze_layers": (tuple(split_names(freeze_layers))
                                   if freeze_layers is not None else None),
                 "aux_weights": tuple(aux_weight) if aux_weight else None,
                 "bootstrap_start_iteration": bootstrap_start,
                 "bootstrap_end_iteration": bootstrap_end,
                 "bootstrap_end_fraction": bootstrap_fraction,
                 "small_object_weight": small_object_weight,
                 "small_object_area_px": small_object_area, "augment": augment,
                 "colour_jitter": colour_jitter, "haze": haze,
                 "distill": distill, "distill_temperature": distill_temperature,
                 "distill_view": distill_view,
                 "train_split": train_split, "val_split": val_split, "val_every": val_every,
                 "checkpoint_every": checkpoint_every, "seed": seed, "device": device,
                 "amp": amp, "num_workers": workers, "threads": threads, "model": model,
                 "init_from": str(init_from) if init_from else None,
                 "val_dirs": [str(d) for d in val_data] if val_data else None}
        if data:
            given["data_dirs"], given["data_weights"] = parse_weighted_data(data)
        stored = load_checkpoint(out / LAST)["config"] if resume else None
        if copy_paste:
            folders = given.get("data_dirs") or (stored["data_dirs"] if stored else [])
            given["copy_paste"] = parse_copy_paste(copy_paste, folders)
        given = {k: v for k, v in given.items() if v is not None}
        if stored is not None:
            config = TrainConfig.from_dict({**stored, **given, "out_dir": str(out)})
        else:
            if model is None or not data:
                raise InputError(None, "model" if model is None else "data",
                                 "a new run needs --model and --data (or --resume)")
            config = TrainConfig(out_dir=str(out), **given)
        result = run_training(config, resume=resume, console=err_console, show_progress=progress)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    best = "—" if result.best_val_miou is None else f"{result.best_val_miou:.4f}"
    console.print(f"trained {config.model} to iteration {result.iteration}; "
                  f"last: {result.last_checkpoint}; best val mIoU {best}"
                  + (f" ({result.best_checkpoint})" if result.best_checkpoint else ""))


@app.command("average-weights")
def average_weights(
    checkpoint: Annotated[list[Path], typer.Option(
        help="Checkpoint to average (repeat: at least two of one network and lineage).")],
    out: Annotated[Path, typer.Option(help="Checkpoint to write (.pt).")],
    weight: Annotated[list[float] | None, typer.Option(
        help="Weight of each --checkpoint, in order [all equal].")] = None,
) -> None:
    """Average the weights of checkpoints of one lineage ("model soup") into a new checkpoint,
    to export or evaluate like any other. With a fine-tune's start.pt (written by a run
    warm-started from an ONNX model) and its best.pt, the weights interpolate between the
    model before and after fine-tuning (WiSE-FT): e.g. --weight 0.5 --weight 0.5 keeps most
    of what the old model knew and much of what the new data taught."""
    need_torch()
    from harborsight.training.checkpoint import average_checkpoints, save_checkpoint

    try:
        prepare_output_file(out, "--out")
        payload = average_checkpoints(checkpoint, weight)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    options = [f"--checkpoint {shlex.quote(str(path))}" for path in checkpoint]
    options += [f"--weight {w:g}" for w in weight or []]
    payload["command"] = " ".join(["harborsight average-weights", *options,
                                   f"--out {shlex.quote(str(out))}"])
    save_checkpoint(out, payload)
    shares = ", ".join(f"{source['weight']:.3g} × {source['path']} (iteration "
                       f"{source['iteration']})" for source in payload["averaged_from"])
    console.print(f"averaged {payload['network']}: {shares}\ncheckpoint: {out}", markup=False,
                  highlight=False)


@app.command("graft-weights")
def graft_weights(
    base: Annotated[Path, typer.Option(help="Checkpoint whose weights are kept (e.g. a fine-tune).")],
    donor: Annotated[Path, typer.Option(
        help="Checkpoint of the same network the named layers come from (e.g. the model the "
             "fine-tune started from).")],
    layers: Annotated[str, typer.Option(
        help="Comma-separated layer groups (the network's top-level modules, e.g. "
             "stem,stage1,stage2 for DDRNet) to take from --donor.")],
    out: Annotated[Path, typer.Option(help="Checkpoint to write (.pt).")],
) -> None:
    """Copy some layer groups' weights from one checkpoint into another of the same network,
    to export or evaluate like any other. With a fine-tune as --base and its start as
    --donor, --layers stem,stage1,stage2 keeps the start's low-level features and the
    fine-tune's deeper layers: a fine-tune on real photos can lose synthetic accuracy in its
    early layers alone (docs/results.md). An unknown group is an error that lists the
    network's groups."""
    need_torch()
    from harborsight.training.checkpoint import graft_checkpoints, save_checkpoint

    groups = split_names(layers)
    try:
        prepare_output_file(out, "--out")
        payload = graft_checkpoints(base, donor, groups)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    payload["command"] = (f"harborsight graft-weights --base {shlex.quote(str(base))} --donor "
                          f"{shlex.quote(str(donor))} --layers {','.join(groups)} "
                          f"--out {shlex.quote(str(out))}")
    save_checkpoint(out, payload)
    grafted = payload["grafted_from"]
    console.print(f"grafted {payload['network']}: {grafted['tensors']} tensors of "
                  f"{', '.join(groups)} from {donor}, the rest from {base}\ncheckpoint: {out}",
                  markup=False, highlight=False)


@app.command("export")
def export_command(
    checkpoint: Annotated[Path, typer.Option(help="Checkpoint from harborsight train (best.pt).")],
    out: Annotated[Path, typer.Option(help="ONNX file to write; the sidecar goes beside it (.json).")],
    height: Annotated[int | None, typer.Option(
        min=1, help="Input rows (default: the training frames' height).")] = None,
    width: Annotated[int | None, typer.Option(
        min=1, help="Input columns (default: the training frames' width).")] = None,
    int8: Annotated[bool, typer.Option(
        help="Also write a statically quantised int8 model (<out>.int8.onnx).")] = False,
    calibration_data: Annotated[list[Path] | None, typer.Option(
        help="Dataset folder(s) for int8 calibration, the fp32/int8 mIoU check and the "
        "ONNX-vs-torch check images.")] = None,
    calibration_split: Annotated[list[str] | None, typer.Option(
        help="Split(s) of the calibration data to use [all].")] = None,
    calibration_frames: Annotated[int, typer.Option(
        min=1, help="Frames used to calibrate the int8 ranges.")] = 16,
    calibration_method: Annotated[str, typer.Option(
        help="How the int8 activation ranges are set: minmax (every value seen) or percentile "
        "(clipped to --calibration-percentile of the values seen).")] = "minmax",
    calibration_percentile: Annotated[float, typer.Option(
        help="Percentile for --calibration-method percentile.")] = DEFAULT_CALIBRATION_PERCENTILE,
) -> None:
    """Export a checkpoint to ONNX (uint8 BGR in, logits and labels out) with a JSON sidecar."""
    try:        # before anything is loaded or made
        check_calibration(calibration_method, calibration_percentile, "--calibration-method",
                          "--calibration-percentile")
    except InputError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    need_torch()
    from harborsight.training.export import export_checkpoint

    try:
        prepare_output_file(out, "--out")
        result = export_checkpoint(checkpoint, out, height, width, int8, calibration_data,
                                   calibration_split, calibration_frames, calibration_method,
                                   calibration_percentile)
    except HarborsightError as exc:
        err_console.print(f"error: {exc}", markup=False, highlight=False)
        raise typer.Exit(2) from None
    for _, error in result.skipped_frames:
        err_console.print(f"[red]skipped calibration frame[/] {escape(error)}", highlight=False)
    console.print(f"ONNX: {result.onnx_path}\nsidecar: {result.sidecar_path}")
    relative = result.max_abs_difference / max(result.max_abs_logit, 1e-12)
    console.print(f"ONNX Runtime vs torch: max |logit difference| {result.max_abs_difference:.2e} "
                  f"(logits up to {result.max_abs_logit:.2e}; relative {relative:.1e})")
    if result.int8_path:
        int8_info = result.sidecar["int8"]
        console.print(f"int8: {result.int8_path}; mIoU fp32 {fmt_number(result.miou_fp32, 4)}, "
                      f"int8 {fmt_number(result.miou_int8, 4)} on {int8_info['evaluation_frames']} "
                      f"frame(s); labels agree on {100 * result.int8_label_agreement:.2f}% of pixels")
