"""Bootstrapped cross-entropy (Wu, Shen & van den Hengel 2016), as the paper trains with.

For each image, the per-pixel cross-entropy is computed over its valid pixels (label
``!= ignore_index``) and only the hardest ``k = ceil(keep_fraction · n_valid)`` are averaged:

    L_i = (1/k) · Σ_{j in top-k(ℓ_i)} ℓ_ij,   ℓ_ij = -log softmax(z_ij)[y_ij]
    L   = mean_i L_i

``keep_fraction`` is annealed by :func:`bootstrap_keep_fraction`: 100 % of the pixels until
iteration 1000, then linearly down to 20 % at iteration 9000, and 20 % after that.

Optional per-pixel weights ``w_ij`` (e.g. :func:`harborsight.training.dataset.small_object_weights`)
scale each pixel's loss before the hardest are chosen, ``ℓ_ij -> w_ij · ℓ_ij``; with all
weights 1 the loss is unchanged.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from harborsight.perception.classes import IGNORE


def bootstrap_keep_fraction(
    iteration: int, start_iteration: int = 1000, end_iteration: int = 9000,
    start_fraction: float = 1.0, end_fraction: float = 0.2,
) -> float:
    """Linearly annealed share of pixels kept, clamped outside [start, end] iterations."""
    if end_iteration <= start_iteration:
        return end_fraction if iteration >= end_iteration else start_fraction
    t = min(max((iteration - start_iteration) / (end_iteration - start_iteration), 0.0), 1.0)
    return start_fraction + t * (end_fraction - start_fraction)


def bootstrapped_cross_entropy(
    logits: torch.Tensor, target: torch.Tensor, keep_fraction: float,
    ignore_index: int = IGNORE, pixel_weights: torch.Tensor | None = None,
) -> torch.Tensor:
    """Mean over images of the mean (weighted) cross-entropy of each image's hardest pixels.

    Shape: ``logits (N, C, H, W)``, ``target (N, H, W)`` long, ``pixel_weights (N, H, W)``.
    An image without valid pixels contributes zero (and keeps the graph connected).
    """
    if logits.ndim != 4 or target.shape != (logits.shape[0], *logits.shape[2:]):
        raise ValueError(f"expected logits (N, C, H, W) and target (N, H, W), got "
                         f"{tuple(logits.shape)} and {tuple(target.shape)}")
    if not 0.0 < keep_fraction <= 1.0:
        raise ValueError(f"keep_fraction must be in (0, 1], got {keep_fraction}")
    n = logits.shape[0]
    pixel_loss = F.cross_entropy(logits, target, ignore_index=ignore_index, reduction="none")
    if pixel_weights is not None:
        if pixel_weights.shape != target.shape:
            raise ValueError(f"pixel_weights {tuple(pixel_weights.shape)} differ from target "
                             f"{tuple(target.shape)}")
        pixel_loss = pixel_loss * pixel_weights
    pixel_loss = pixel_loss.reshape(n, -1)
    valid = (target != ignore_index).reshape(n, -1)
    per_image = []
    for i in range(n):
        losses = pixel_loss[i][valid[i]]
        if losses.numel() == 0:
            per_image.append(logits[i].sum() * 0.0)
            continue
        k = max(1, math.ceil(keep_fraction * losses.numel()))
        per_image.append(torch.topk(losses, k, sorted=False).values.mean())
    return torch.stack(per_image).mean()


class BootstrappedCrossEntropy(nn.Module):
    """Module form of :func:`bootstrapped_cross_entropy` with the annealing schedule."""

    def __init__(self, start_iteration: int = 1000, end_iteration: int = 9000,
                 end_fraction: float = 0.2, ignore_index: int = IGNORE) -> None:
        super().__init__()
        self.start_iteration = start_iteration
        self.end_iteration = end_iteration
        self.end_fraction = end_fraction
        self.ignore_index = ignore_index

    def forward(self, logits: torch.Tensor, target: torch.Tensor, iteration: int) -> torch.Tensor:
        keep = bootstrap_keep_fraction(iteration, self.start_iteration, self.end_iteration,
                                       1.0, self.end_fraction)
        return bootstrapped_cross_entropy(logits, target, keep, self.ignore_index)


def agreeing_distillation_loss(
    student_logits: torch.Tensor, teacher_logits: torch.Tensor, target: torch.Tensor,
    temperature: float = 2.0, ignore_index: int = IGNORE,
) -> torch.Tensor:
    """Knowledge distillation from a frozen teacher on the pixels it labels correctly.

    Learning without Forgetting (Li & Hoiem 2016) keeps a fine-tuned network close to the
    network it started from by matching the starting network's softened outputs. Here the
    match is restricted to the valid pixels where the teacher's argmax equals the label
    (on simulator frames nearly all of them; on a real frame only those the teacher already
    gets right), so the teacher never pulls against a label:

        L = T² · (1/|K|) · Σ_{j in K} KL( softmax(t_j / T) ‖ softmax(s_j / T) ),
        K = { j : y_j ≠ ignore, argmax t_j = y_j }

    ``T²`` keeps the gradient's size independent of ``T`` (Hinton et al. 2015). Shapes:
    ``(N, C, H, W)`` logits, ``(N, H, W)`` long target. No kept pixel: zero, graph connected.
    """
    if student_logits.shape != teacher_logits.shape:
        raise ValueError(f"student logits {tuple(student_logits.shape)} differ from teacher "
                         f"logits {tuple(teacher_logits.shape)}")
    if not temperature > 0:
        raise ValueError(f"temperature must be positive, got {temperature}")
    keep = (target != ignore_index) & (teacher_logits.argmax(dim=1) == target)
    if not bool(keep.any()):
        return student_logits.sum() * 0.0
    log_student = F.log_softmax(student_logits.float() / temperature, dim=1)
    log_teacher = F.log_softmax(teacher_logits.float() / temperature, dim=1)
    per_pixel = F.kl_div(log_student, log_teacher, reduction="none", log_target=True).sum(dim=1)
    return temperature ** 2 * per_pixel[keep].mean()
