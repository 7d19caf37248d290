"""Real-time segmentation networks in plain torch, and a plain-dict factory.

Every network takes ``(N, 3, H, W)`` with H and W multiples of its ``output_stride`` and
returns logits at the input size; in training mode, networks with auxiliary heads return
``(logits, [aux, ...])``. Modules used only in training live under ``aux_heads``, so the
inference graph is everything else (:func:`inference_parameter_count`).
"""

from __future__ import annotations

from torch import nn

from harborsight.perception.networks.bisenetv2 import BiSeNetV2
from harborsight.perception.networks.ddrnet import DDRNet23, DDRNet23Slim
from harborsight.perception.networks.hardnet import FCHarDNet70

NETWORKS: dict[str, type[nn.Module]] = {
    "bisenetv2": BiSeNetV2,
    "fchardnet70": FCHarDNet70,
    "ddrnet23_slim": DDRNet23Slim,
    "ddrnet23": DDRNet23,
}


def create_network(name: str, num_classes: int = 3, aux_heads: bool = True, **options) -> nn.Module:
    """Build a network by name (see :data:`NETWORKS`); ``options`` go to its constructor
    (checkpoints record them as ``network_options``)."""
    if name not in NETWORKS:
        raise ValueError(f"unknown network {name!r}; choose from {sorted(NETWORKS)}")
    return NETWORKS[name](num_classes=num_classes, aux_heads=aux_heads, **options)


def parameter_count(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def inference_parameter_count(network: nn.Module) -> int:
    """Parameters of the inference graph: all but those under ``network.aux_heads``."""
    aux = getattr(network, "aux_heads", None)
    return parameter_count(network) - (parameter_count(aux) if aux is not None else 0)


def layer_groups(network: nn.Module) -> list[str]:
    """The network's top-level modules that hold weights or buffers (``stem``, ``stage1``,
    ... for DDRNet), in order: the groups ``train --freeze-layers`` and ``graft-weights
    --layers`` name."""
    return [name for name, child in network.named_children() if child.state_dict()]
