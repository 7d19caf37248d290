"""The training loop: the paper's recipe (SGD, poly LR, per-image bootstrapped CE) with
deep-supervision heads, validation mIoU, atomic checkpoints and an exact resume.

Per iteration ``i`` (0-based) with ``T`` iterations in all:

    lr_i   = lr · (1 - i/T)^power · w_i                    (poly; no decay on 1-D params)
    w_i    = r + (1 - r)·i/W for i < W, else 1             (optional linear warm-up, W iters)
    k_i    = bootstrap keep fraction (100 % -> 20 % between iterations 1000 and 9000)
    loss_i = BCE_k(main) + Σ_h w_h · BCE_k(aux_h)          (w: per-network aux weights)
             + λ · KD_T(main, teacher)                      (optional, λ = ``distill``)

With ``distill`` λ > 0 (a warm start only), the network the run started from is kept frozen
as a teacher and the main head is also pulled toward the teacher's softened outputs on the
pixels the teacher labels correctly
(:func:`harborsight.training.losses.agreeing_distillation_loss`): a fine-tune on real frames
then forgets less of what the simulator frames taught. The teacher sees the student's input
(``distill_view="augmented"``) or the same crop before its photometric augmentation
(``"clean"``): then on a hazed or colour-shifted sample it still knows the clear view's
answer, and the student is pulled to give it through the haze.

With ``copy_paste`` (a probability per dataset folder, 0 for most), a sample of that folder
first gets 1-3 of the folder's own training vessels pasted onto its open water
(:mod:`harborsight.training.copy_paste`), drawn from a generator seeded by ``(seed, 3, n)``
so that every other draw of the sample is the same with or without it.

With ``small_object_weight`` > 1, each pixel's cross-entropy is first multiplied by its
small-object weight ``clip(sqrt(A_ref / A_k), 1, small_object_weight)``, ``A_k`` the visible
area in pixels of the object it belongs to (the dataset's ``instances/`` masks;
:func:`harborsight.training.dataset.small_object_weights`): fenders and buoys are a few dozen
pixels, and a pixel-averaged loss barely sees them.

Samples are a pure function of ``(seed, sample number)``: training sample ``n = i·B + j`` is
frame ``perm_e[n mod N]`` of the permutation ``perm_e`` seeded by ``(seed, e)``, ``e = n div N``,
augmented with a generator seeded by ``(seed, n)``. With dataset weights ``w_k`` (mixed
training, e.g. simulator and real frames), sample ``n`` instead draws its dataset ``k`` with
probability ``w_k / Σw`` and a frame of it uniformly, both from a generator seeded by
``(seed, 2, n)``: each dataset's share of the samples is its weight, whatever its size.
Together with the model, optimiser and torch RNG state saved in ``last.pt``, a resumed run
repeats an uninterrupted one exactly (same device, same thread count), with or without
DataLoader workers. Workers are spawned,
not forked (OpenCV's thread pool deadlocks in a forked child), so a script that trains with
workers needs the usual ``if __name__ == "__main__":`` guard.

A warm start (``init_from``, a checkpoint of the same network, or an ONNX model written by
``harborsight export`` such as the shipped default) only replaces the initial weights and
takes the source's network options: optimiser, schedule and sampling start at iteration 0,
as in a fresh run.

Outputs in ``out_dir``: ``last.pt`` (every ``checkpoint_every`` iterations and at the end),
``best.pt`` (highest validation mIoU), ``train_log.jsonl`` (one JSON object per iteration
and per validation, written line by line), and for a warm start from an ONNX model
or a distilling run ``start.pt``: the starting weights at iteration 0 (a distilling run's
teacher), the other end of a weight-space interpolation (``average-weights --checkpoint
start.pt --checkpoint best.pt``, WiSE-FT).

The run's settings live in :mod:`harborsight.training.config`, the sample stream in
:mod:`harborsight.training.samples` and the warm start in :mod:`harborsight.training.warm_start`.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.markup import escape

from harborsight.errors import HarborsightError, InputError
from harborsight.evaluation.segmentation import SegmentationScores, score_frames
from harborsight.perception.classes import CLASS_NAMES, NUM_CLASSES
from harborsight.perception.model import SegmentationModel, TorchSegmenter
from harborsight.perception.networks import create_network
from harborsight.progress import progress_report
from harborsight.training.augment import AugmentConfig
from harborsight.training.checkpoint import (
    CHECKPOINT_FORMAT,
    CURRENT_NETWORK_OPTIONS,
    load_checkpoint,
    model_from_checkpoint,
    network_options,
    save_checkpoint,
)
from harborsight.training.config import (
    RESUMABLE_CHANGES,
    TrainConfig,
)
from harborsight.training.dataset import SegmentationFrames
from harborsight.training.losses import (
    agreeing_distillation_loss,
    bootstrap_keep_fraction,
    bootstrapped_cross_entropy,
)
from harborsight.training.optim import parameter_groups, poly_learning_rate
from harborsight.training.samples import TrainingSamples, data_workers, worker_init
from harborsight.training.warm_start import apply_initial_weights, load_initial_weights

LAST, BEST, LOG, START = "last.pt", "best.pt", "train_log.jsonl", "start.pt"


class TrainingDivergedError(HarborsightError):
    """The loss stopped being finite."""


def resolve_device(name: str) -> torch.device:
    """``auto`` -> ``cuda`` when available, else ``cpu``; a named CUDA device must exist."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(None, "device", f"{name} requested but CUDA is not available")
    return torch.device(name)


def learning_rate(config: TrainConfig, iteration: int) -> float:
    """Poly schedule times the linear warm-up factor (module docstring)."""
    lr = poly_learning_rate(config.lr, iteration, config.iterations, config.poly_power)
    if iteration < config.warmup_iterations:
        r = config.warmup_ratio
        lr *= r + (1.0 - r) * iteration / config.warmup_iterations
    return lr


@dataclass
class TrainResult:
    out_dir: Path
    iteration: int
    losses: list[float] = field(default_factory=list)   # of the iterations run in this call
    val_miou: float | None = None
    best_val_miou: float | None = None

    @property
    def last_checkpoint(self) -> Path:
        return self.out_dir / LAST

    @property
    def best_checkpoint(self) -> Path | None:
        path = self.out_dir / BEST
        return path if path.is_file() else None


def _aux_losses(output, target: torch.Tensor, keep: float, weights: tuple[float, ...],
                pixel_weights: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    main, aux = output if isinstance(output, tuple) else (output, [])
    if len(aux) != len(weights):
        raise RuntimeError(f"network returned {len(aux)} auxiliary outputs for {len(weights)} weights")
    main_loss = bootstrapped_cross_entropy(main.float(), target, keep,
                                           pixel_weights=pixel_weights)
    total = main_loss
    for weight, logits in zip(weights, aux, strict=True):
        if weight:
            total = total + weight * bootstrapped_cross_entropy(logits.float(), target, keep,
                                                                pixel_weights=pixel_weights)
    return total, main_loss


def validate(model: SegmentationModel, frames: SegmentationFrames, device: torch.device,
             amp: bool = False) -> SegmentationScores:
    """Confusion-matrix scores of the model in eval mode on whole frames (batch 1)."""
    was_training = model.training
    model.eval()
    try:
        return score_frames(TorchSegmenter(model, device, amp).segment, frames)
    finally:
        model.train(was_training)


def training_mode(model: torch.nn.Module, freeze_batchnorm: bool = False,
                  frozen_layers: tuple[str, ...] | None = None) -> None:
    """The model in training mode; with ``freeze_batchnorm`` its BatchNorm layers stay in
    eval mode: they normalise with their running statistics and do not update them (their
    affine scale and shift still receive gradients). The ``frozen_layers`` (see
    :func:`freeze_layer_groups`) stay in eval mode whole."""
    model.train()
    if freeze_batchnorm:
        for module in model.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.eval()
    for group in frozen_layers or ():
        module = getattr(model.network, group, None)      # a teacher has no aux heads
        if module is not None:
            module.eval()


def freeze_layer_groups(model: SegmentationModel, groups: tuple[str, ...] | None) -> int:
    """Stop the named layer groups of ``model.network`` from learning: their parameters get no
    gradient (and so no optimiser state) and their BatchNorm statistics stay as they are
    (:func:`training_mode`). Tuning only some blocks can adapt better to a shift than tuning
    all (Lee et al. 2022, surgical fine-tuning); here the first layers keep the simulator's
    low-level features (docs/results.md). Returns how many parameter tensors were frozen."""
    frozen = 0
    for group in groups or ():
        for parameter in getattr(model.network, group).parameters():
            parameter.requires_grad_(False)
            frozen += 1
    return frozen


def validate_sets(model: SegmentationModel, val_sets: list[tuple[str, SegmentationFrames]],
                  device: torch.device, amp: bool = False) -> tuple[float, dict]:
    """Validation over one or more datasets, and the mIoU that picks ``best.pt``.

    One dataset: its mIoU. Several: the mean of their mIoUs, each scored on its own, so that
    a small real set counts as much as a large simulator set (pooling pixels would let the
    larger set decide alone). The record holds the pooled scores too, and each set's."""
    per_set = {name: validate(model, frames, device, amp) for name, frames in val_sets}
    pooled = SegmentationScores(sum(s.confusion for s in per_set.values()))
    scores = {k: v for k, v in pooled.to_dict().items() if k != "confusion"}
    if len(per_set) == 1:
        return pooled.miou, scores
    selection_miou = float(np.mean([s.miou for s in per_set.values()]))
    return selection_miou, {**scores, "pooled_miou": scores["miou"], "miou": selection_miou,
                            "selection": "mean of per-dataset mIoU",
                            "per_dataset": {name: {"miou": s.miou, "iou": s.to_dict()["iou"]}
                                            for name, s in per_set.items()}}


def _frozen_teacher(path: Path, device: torch.device, freeze_batchnorm: bool,
                    frozen_layers: tuple[str, ...] | None = None) -> SegmentationModel:
    """The network a distilling run started from (``start.pt``), its weights frozen, in the
    student's mode: BatchNorm normalises as the student's does (batch statistics, or the
    running ones with ``freeze_batchnorm``), so at iteration 0 both compute the same outputs
    and the distillation loss is zero (the student's frozen layer groups run in eval mode in
    both). (A teacher in eval mode would pull a student that normalises by batch statistics
    toward another function.)"""
    teacher = model_from_checkpoint(path).to(device)
    for parameter in teacher.parameters():
        parameter.requires_grad_(False)
    training_mode(teacher, freeze_batchnorm, frozen_layers)
    return teacher


def _best_so_far(best_miou: float | None, best_path: Path) -> float | None:
    """The best validation mIoU a resumed run has to beat: last.pt's, or best.pt's when an
    interrupted run wrote a better best.pt after its last checkpoint (a best.pt the run
    keeps and must not overwrite with a worse one)."""
    if not best_path.is_file():
        return best_miou
    written = load_checkpoint(best_path).get("best_val_miou")
    if written is None or (best_miou is not None and best_miou >= written):
        return best_miou
    return float(written)


def _truncate_log(path: Path, iteration: int) -> None:
    """Drop log lines written after ``iteration`` (by a run that was then interrupted), and
    any line such a run left half-written when it was killed."""
    if not path.is_file():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            if json.loads(line)["iteration"] <= iteration:
                kept.append(line)
        except (ValueError, KeyError, TypeError):
            continue
    path.write_text("".join(f"{line}\n" for line in kept))


def _check_resume(stored: TrainConfig, given: TrainConfig, path: Path) -> None:
    a, b = stored.to_dict(), given.to_dict()
    a["data_dirs"] = [str(Path(d).resolve()) for d in a["data_dirs"]]
    b["data_dirs"] = [str(Path(d).resolve()) for d in b["data_dirs"]]
    changed = [k for k in a if k not in RESUMABLE_CHANGES and a[k] != b.get(k)]
    if changed:
        details = ", ".join(f"{k}: {a[k]!r} -> {b.get(k)!r}" for k in changed)
        raise InputError(path, "config", f"resume must keep the run's settings; changed {details}")


def train(
    config: TrainConfig, resume: bool = False, until_iteration: int | None = None,
    console: Console | None = None, show_progress: bool = True,
) -> TrainResult:
    """Train (or resume) per ``config``; stops after ``until_iteration`` iterations if given
    (writing ``last.pt`` there), otherwise after ``config.iterations``. ``config.threads``
    applies for the duration of the call only."""
    previous_threads = torch.get_num_threads()
    if config.threads:
        torch.set_num_threads(config.threads)
    try:
        return _train(config, resume, until_iteration, console or Console(stderr=True),
                      show_progress)
    finally:
        torch.set_num_threads(previous_threads)


def _train(config: TrainConfig, resume: bool, until_iteration: int | None, console: Console,
           show_progress: bool) -> TrainResult:
    out_dir = Path(config.out_dir)
    last_path, best_path, log_path = out_dir / LAST, out_dir / BEST, out_dir / LOG
    device = resolve_device(config.device)
    use_amp = config.amp and device.type == "cuda"
    stop = min(config.iterations, until_iteration or config.iterations)

    checkpoint = None
    if resume:
        checkpoint = load_checkpoint(last_path)
        stored = TrainConfig.from_dict(checkpoint["config"])
        _check_resume(stored, config, last_path)
        if stored.iterations != config.iterations:
            console.print(f"[yellow]note:[/] --iterations {stored.iterations} -> "
                          f"{config.iterations}: the poly learning-rate schedule is stretched "
                          "from here on, so this is no longer the run the first command "
                          "described")
    elif last_path.exists():
        raise InputError(last_path, None, "a run already lives here: resume it (--resume) or "
                         "choose another --out")

    train_frames = SegmentationFrames(config.data_dirs, [config.train_split], config.fit_large_hw)
    skipped = train_frames.drop_unreadable(instances=config.small_object_weight > 1.0)
    val_sets: list[tuple[str, SegmentationFrames]] = []
    if config.val_every:
        try:
            for val_dir in config.val_dirs or config.data_dirs:
                try:
                    frames = SegmentationFrames([val_dir], [config.val_split], config.fit_large_hw)
                except InputError:
                    if config.val_dirs is not None:     # a folder named for validation must
                        raise                           # have val frames; a --data folder need not
                    continue
                skipped += frames.drop_unreadable()
                val_sets.append((str(val_dir), frames))
            if not val_sets:                            # the error of the folders taken together
                SegmentationFrames(config.data_dirs, [config.val_split]).drop_unreadable()
        except InputError as exc:
            raise InputError(exc.source, exc.field, f"{exc.message} (train without validation "
                             "with --val-every 0)") from None
    for _, reason in skipped:
        console.print(f"[red]skipped frame[/] {escape(reason)}", highlight=False)
    frames_id = {"count": len(train_frames), "sha1": train_frames.fingerprint()}
    if checkpoint is not None and checkpoint.get("train_frames", frames_id) != frames_id:
        then = checkpoint["train_frames"]["count"]
        raise InputError(last_path, "train_frames", f"the training frames changed since the run "
                         f"began ({then} then, {len(train_frames)} readable now): the sampling "
                         "order would change; train the new set as a new run (--init-from)")

    torch.manual_seed(config.seed)
    # a resumed run keeps the architecture it began with, a warm start its source's, a new
    # one takes the current
    initial = None
    if checkpoint is None and config.init_from:
        initial = load_initial_weights(config, train_frames)
        torch.manual_seed(config.seed)  # the recovery may draw random numbers
    if checkpoint is not None:
        options = network_options(checkpoint)
    elif initial is not None:
        options = initial.options
    else:
        options = CURRENT_NETWORK_OPTIONS.get(config.model, {})
    model = SegmentationModel(create_network(config.model, NUM_CLASSES, aux_heads=True,
                                             **options)).to(device)
    freeze_layer_groups(model, config.freeze_layers)
    training_mode(model, config.freeze_batchnorm, config.freeze_layers)
    optimizer = torch.optim.SGD(parameter_groups(model, config.weight_decay), lr=config.lr,
                                momentum=config.momentum)
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp)
    start, best_miou, val_miou = 0, None, None
    initial_weights = None
    if checkpoint is not None:
        initial_weights = checkpoint.get("init_from")
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        if checkpoint.get("scaler"):
            scaler.load_state_dict(checkpoint["scaler"])
        torch.set_rng_state(checkpoint["rng"]["torch"])
        if device.type == "cuda" and checkpoint["rng"].get("cuda"):
            torch.cuda.set_rng_state_all(checkpoint["rng"]["cuda"])
        start = int(checkpoint["iteration"])
        best_miou, val_miou = checkpoint.get("best_val_miou"), checkpoint.get("val_miou")
        best_miou = _best_so_far(best_miou, best_path)
        _truncate_log(log_path, start)
    elif initial is not None:
        apply_initial_weights(model, initial, config.init_from)
        initial_weights = initial.provenance
    out_dir.mkdir(parents=True, exist_ok=True)
    if checkpoint is None:  # a fresh run: nothing of an earlier, unfinished one may survive
        log_path.unlink(missing_ok=True)
        best_path.unlink(missing_ok=True)
        (out_dir / START).unlink(missing_ok=True)
    if device.type == "cuda":
        # fastest kernels; their choice may vary between runs, so a CUDA resume is exact only
        # up to floating-point summation order (a CPU resume is bit-exact)
        torch.backends.cudnn.benchmark = True
    frame_hw = list(train_frames.common_size_hw())

    def payload(iteration: int, full: bool) -> dict:
        """A checkpoint; ``full`` adds what an exact resume needs (optimiser, scaler, RNG)."""
        data = {
            "format": CHECKPOINT_FORMAT, "network": config.model, "network_options": options,
            "num_classes": NUM_CLASSES, "class_names": list(CLASS_NAMES),
            "iteration": iteration, "model": model.state_dict(),
            "optimizer": None, "scaler": None, "rng": None,
            "config": config.to_dict(), "command": config.command_line(), "frame_hw": frame_hw,
            "val_miou": val_miou, "best_val_miou": best_miou, "init_from": initial_weights,
            "train_frames": frames_id, "skipped_frames": [path for path, _ in skipped],
        }
        if full:
            data["optimizer"] = optimizer.state_dict()
            data["scaler"] = scaler.state_dict() if use_amp else None
            data["rng"] = {"torch": torch.get_rng_state(),
                           "cuda": torch.cuda.get_rng_state_all() if device.type == "cuda" else None}
        return data

    if initial is not None and (initial.provenance.get("onnx") or config.distill > 0):
        # recovered from ONNX: no checkpoint file holds these weights, and an interpolation
        # with the fine-tuned ones needs exactly them (same rebuilt BatchNorm statistics);
        # a distilling run's teacher is rebuilt from it on resume
        save_checkpoint(out_dir / START, payload(0, full=False))
    teacher = (_frozen_teacher(out_dir / START, device, config.freeze_batchnorm,
                               config.freeze_layers) if config.distill > 0 else None)

    jitter = config.colour_jitter
    augmentation = (AugmentConfig(crop_hw=config.crop_hw, brightness=jitter, contrast=jitter,
                                  saturation=jitter, p_haze=config.haze) if config.augment
                    else AugmentConfig.geometric_only(config.crop_hw))
    samples = TrainingSamples(train_frames, config.seed, augmentation,
                              config.small_object_weight, config.small_object_area_px,
                              config.data_weights,
                              clean_view=teacher is not None and config.distill_view == "clean",
                              copy_paste=config.copy_paste)
    batch = config.batch_size
    workers = data_workers(config.num_workers, device)
    loader = torch.utils.data.DataLoader(
        samples, batch_size=batch, sampler=range(start * batch, stop * batch),
        num_workers=workers, pin_memory=device.type == "cuda",
        # spawned, not forked: OpenCV and OpenMP thread pools do not survive a fork
        multiprocessing_context="spawn" if workers else None,
        worker_init_fn=worker_init if workers else None,
        generator=torch.Generator().manual_seed(config.seed),   # keeps the global RNG untouched
    )
    weights = config.effective_aux_weights
    result = TrainResult(out_dir, start, val_miou=val_miou, best_val_miou=best_miou)
    miou_text = "—" if val_miou is None else f"{val_miou:.3f}"

    def status(loss_value: float, lr: float, keep: float) -> str:
        return f"loss {loss_value:.4f}, lr {lr:.2e}, keep {keep:.0%}, val mIoU {miou_text}"

    t0 = time.perf_counter()
    # line-buffered: each iteration's line is on disk at once, for `tail -f` and after a kill
    log = log_path.open("a", buffering=1)
    with log, progress_report(f"training {config.model}", config.iterations, console,
                              unit="iterations", transient=False, enabled=show_progress,
                              completed=start, remaining=True) as progress:
        progress.update(note=status(math.nan, config.lr, 1.0))
        iteration = start
        for images, labels, pixel_weights, *clean in loader:
            lr = learning_rate(config, iteration)
            for group in optimizer.param_groups:
                group["lr"] = lr
            keep = bootstrap_keep_fraction(iteration, config.bootstrap_start_iteration,
                                           config.bootstrap_end_iteration, 1.0,
                                           config.bootstrap_end_fraction)
            images = images.to(device, non_blocking=True)
            target = labels.to(device, non_blocking=True).long()
            pixel_weights = (pixel_weights.to(device, non_blocking=True)
                             if config.small_object_weight > 1.0 else None)
            with torch.autocast(device.type, torch.float16, enabled=use_amp):
                output = model(images)
            loss, main_loss = _aux_losses(output, target, keep, weights, pixel_weights)
            distill_loss = None
            if teacher is not None:
                seen = clean[0].to(device, non_blocking=True) if clean else images
                with torch.no_grad(), torch.autocast(device.type, torch.float16, enabled=use_amp):
                    teacher_logits = teacher(seen)
                main = output[0] if isinstance(output, tuple) else output
                distill_loss = agreeing_distillation_loss(main, teacher_logits, target,
                                                          config.distill_temperature)
                loss = loss + config.distill * distill_loss
            optimizer.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.step(optimizer)
            scaler.update()
            iteration += 1
            loss_value = float(loss.detach())
            if not math.isfinite(loss_value):
                raise TrainingDivergedError(
                    f"loss became {loss_value} at iteration {iteration}; lower --lr or add a "
                    f"--warmup ({last_path} keeps the last checkpointed state)")
            result.losses.append(loss_value)
            log.write(json.dumps({"iteration": iteration, "kind": "train", "loss": loss_value,
                                  "loss_main": float(main_loss.detach()), "lr": lr,
                                  **({} if distill_loss is None else
                                     {"loss_distill": float(distill_loss.detach())}),
                                  "keep_fraction": keep,
                                  "elapsed_s": round(time.perf_counter() - t0, 3)}) + "\n")
            if val_sets and (iteration % config.val_every == 0 or iteration == config.iterations):
                val_miou, record = validate_sets(model, val_sets, device, use_amp)
                training_mode(model, config.freeze_batchnorm, config.freeze_layers)
                log.write(json.dumps({"iteration": iteration, "kind": "val", **record}) + "\n")
                if math.isfinite(val_miou) and (best_miou is None or val_miou > best_miou):
                    best_miou = val_miou
                    save_checkpoint(best_path, payload(iteration, full=False))
                miou_text = f"{val_miou:.3f}"
            if iteration % config.checkpoint_every == 0 or iteration == stop:
                log.flush()
                save_checkpoint(last_path, payload(iteration, full=True))
            progress.advance(note=status(loss_value, lr, keep))
    result.iteration, result.val_miou, result.best_val_miou = iteration, val_miou, best_miou
    return result
