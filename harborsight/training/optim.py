"""SGD parameter groups and the poly learning-rate schedule of the paper's recipe."""

from __future__ import annotations

from torch import nn


def parameter_groups(model: nn.Module, weight_decay: float) -> list[dict]:
    """Two groups: weight decay on weights of rank >= 2, none on 1-D parameters (biases,
    batch-norm scales and shifts)."""
    decay, no_decay = [], []
    for parameter in model.parameters():
        if not parameter.requires_grad:
            continue
        (no_decay if parameter.ndim <= 1 else decay).append(parameter)
    return [{"params": decay, "weight_decay": weight_decay},
            {"params": no_decay, "weight_decay": 0.0}]


def poly_learning_rate(base_lr: float, iteration: int, max_iterations: int,
                       power: float = 0.9) -> float:
    """``lr = base_lr · (1 - iteration / max_iterations) ** power`` (0 at the end)."""
    progress = min(max(iteration / max_iterations, 0.0), 1.0)
    return base_lr * (1.0 - progress) ** power
