"""DDRNet-23 and DDRNet-23-slim: deep dual-resolution networks for real-time segmentation.

Hong, Pan, Sun and Jia, "Deep Dual-resolution Networks for Real-time and Accurate Semantic
Segmentation of Road Scenes" (arXiv:2101.06085, 2021); reference code: ydhongHIT/DDRNet.

A shared ResNet-style stem (two stride-2 convolutions, then residual stages at 1/4 and 1/8)
splits into two branches after the 1/8 stage:

* a high-resolution branch that stays at 1/8 with ``2w`` channels, and
* a low-resolution branch that keeps halving (1/16, 1/32, 1/64) while widening to ``16w``.

After the 1/16 and 1/32 stages the branches exchange information ("bilateral fusion"): the
high branch is strided down and added to the low branch, and the low branch is compressed by
a 1x1 convolution, upsampled and added to the high branch. At 1/64 the Deep Aggregation
Pyramid Pooling Module (DAPPM) gathers context from average pools of growing size whose
outputs are refined hierarchically (each scale adds the previous one before a 3x3 conv). Its
output is upsampled to 1/8, added to the high branch and decoded by a small segmentation
head. For training, a second head reads the high branch after the first fusion (the deep
supervision of the paper); it lives under ``aux_heads`` and is not part of inference.

Widths follow the reference: DDRNet-23-slim uses ``w = 32`` and a 64-channel head,
DDRNet-23 ``w = 64`` and a 128-channel head; the DAPPM branches have 128 channels in both.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

_BN_MOMENTUM = 0.1


def _norm(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, momentum=_BN_MOMENTUM)


def _resize(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """Bilinear resize of ``x`` to the spatial size of ``like`` (sizes taken from the tensor)."""
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=False)


class _Residual(nn.Module):
    """Residual unit: a basic (two 3x3) or bottleneck (1x1-3x3-1x1, 2x wider output) body.

    The identity path becomes a strided 1x1 conv + BN whenever the shape changes. With
    ``relu_out=False`` the sum is returned before the final activation, as the last unit of
    every stage does in DDRNet (the activation is applied where the output is consumed).
    """

    def __init__(self, in_ch: int, ch: int, stride: int, bottleneck: bool, relu_out: bool) -> None:
        super().__init__()
        out_ch = ch * 2 if bottleneck else ch
        if bottleneck:
            self.body = nn.Sequential(
                nn.Conv2d(in_ch, ch, 1, bias=False), _norm(ch), nn.ReLU(inplace=True),
                nn.Conv2d(ch, ch, 3, stride, 1, bias=False), _norm(ch), nn.ReLU(inplace=True),
                nn.Conv2d(ch, out_ch, 1, bias=False), _norm(out_ch),
            )
        else:
            self.body = nn.Sequential(
                nn.Conv2d(in_ch, ch, 3, stride, 1, bias=False), _norm(ch), nn.ReLU(inplace=True),
                nn.Conv2d(ch, ch, 3, 1, 1, bias=False), _norm(ch),
            )
        if stride != 1 or in_ch != out_ch:
            self.skip: nn.Module = nn.Sequential(
                nn.Conv2d(in_ch, out_ch, 1, stride, bias=False), _norm(out_ch)
            )
        else:
            self.skip = nn.Identity()
        self.act: nn.Module = nn.ReLU(inplace=True) if relu_out else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.body(x) + self.skip(x))


def _stage(in_ch: int, ch: int, depth: int, stride: int = 1, bottleneck: bool = False,
           single_relu: bool = True) -> nn.Sequential:
    """``depth`` residual units; only the first may stride. The last of several skips its
    ReLU; a stage of one unit keeps it (the reference's ``_make_layer`` marks ``no_relu``
    only on the last of two or more blocks), unless ``single_relu=False``."""
    units = []
    for i in range(depth):
        relu_out = i < depth - 1 or (depth == 1 and single_relu)
        units.append(_Residual(in_ch, ch, stride if i == 0 else 1, bottleneck, relu_out))
        in_ch = ch * 2 if bottleneck else ch
    return nn.Sequential(*units)


def _bn_relu_conv(in_ch: int, out_ch: int, kernel: int) -> nn.Sequential:
    """Pre-activation convolution (BN, ReLU, conv without bias) as used in DAPPM and heads."""
    return nn.Sequential(
        _norm(in_ch), nn.ReLU(inplace=True), nn.Conv2d(in_ch, out_ch, kernel, padding=kernel // 2, bias=False)
    )


class _DAPPM(nn.Module):
    """Deep Aggregation Pyramid Pooling Module.

    Five context scales (identity, average pools 5/2, 9/4, 17/8 and a global pool) are each
    squeezed to ``mid_ch`` by a 1x1 conv. Every pooled scale is upsampled, added to the scale
    before it and refined by a 3x3 conv; the five results are concatenated, fused by a 1x1
    conv and added to a 1x1 projection of the input.
    """

    def __init__(self, in_ch: int, mid_ch: int, out_ch: int) -> None:
        super().__init__()
        pools = [
            nn.AvgPool2d(5, stride=2, padding=2),
            nn.AvgPool2d(9, stride=4, padding=4),
            nn.AvgPool2d(17, stride=8, padding=8),
            nn.AdaptiveAvgPool2d(1),
        ]
        self.base = _bn_relu_conv(in_ch, mid_ch, 1)
        self.pooled = nn.ModuleList(nn.Sequential(pool, _bn_relu_conv(in_ch, mid_ch, 1)) for pool in pools)
        self.refine = nn.ModuleList(_bn_relu_conv(mid_ch, mid_ch, 3) for _ in pools)
        self.fuse = _bn_relu_conv(mid_ch * (len(pools) + 1), out_ch, 1)
        self.project = _bn_relu_conv(in_ch, out_ch, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scales = [self.base(x)]
        for squeeze, refine in zip(self.pooled, self.refine, strict=True):
            scales.append(refine(_resize(squeeze(x), x) + scales[-1]))
        return self.fuse(torch.cat(scales, dim=1)) + self.project(x)


class _SegHead(nn.Module):
    """BN-ReLU-3x3 conv to ``mid_ch``, then BN-ReLU-1x1 conv (with bias) to class logits."""

    def __init__(self, in_ch: int, mid_ch: int, num_classes: int) -> None:
        super().__init__()
        self.features = _bn_relu_conv(in_ch, mid_ch, 3)
        self.classify = nn.Sequential(
            _norm(mid_ch), nn.ReLU(inplace=True), nn.Conv2d(mid_ch, num_classes, 1, bias=True)
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.classify(self.features(x))


class _DDRNet23(nn.Module):
    """DDRNet-23 family with base width ``width`` (stage channels w, 2w, 4w, 8w, 16w).

    ``layer5_relu=False`` rebuilds the network harborsight trained before 2026-11-23, whose
    one-unit bottleneck stages (``low5``, ``high5``) ended without the ReLU the reference
    applies; checkpoints written then say so by lacking ``network_options``.
    """

    name = "ddrnet23_base"
    output_stride = 32

    def __init__(
        self, num_classes: int, aux_heads: bool, width: int, head_width: int, dappm_width: int = 128,
        layer5_relu: bool = True,
    ) -> None:
        super().__init__()
        w = width
        high_ch = 2 * w
        self.stem = nn.Sequential(
            nn.Conv2d(3, w, 3, stride=2, padding=1), _norm(w), nn.ReLU(inplace=True),
            nn.Conv2d(w, w, 3, stride=2, padding=1), _norm(w), nn.ReLU(inplace=True),
        )
        # Shared trunk at 1/4 and 1/8.
        self.stage1 = _stage(w, w, 2)
        self.stage2 = _stage(w, 2 * w, 2, stride=2)
        # Low-resolution branch: 1/16, 1/32, then a bottleneck unit to 1/64.
        self.low3 = _stage(2 * w, 4 * w, 2, stride=2)
        self.low4 = _stage(4 * w, 8 * w, 2, stride=2)
        self.low5 = _stage(8 * w, 8 * w, 1, stride=2, bottleneck=True, single_relu=layer5_relu)
        # High-resolution branch, kept at 1/8.
        self.high3 = _stage(2 * w, high_ch, 2)
        self.high4 = _stage(high_ch, high_ch, 2)
        self.high5 = _stage(high_ch, high_ch, 1, bottleneck=True, single_relu=layer5_relu)
        # Bilateral fusion: high -> low by strided 3x3 convs, low -> high by 1x1 compression.
        self.high_to_low3 = nn.Sequential(nn.Conv2d(high_ch, 4 * w, 3, 2, 1, bias=False), _norm(4 * w))
        self.high_to_low4 = nn.Sequential(
            nn.Conv2d(high_ch, 4 * w, 3, 2, 1, bias=False), _norm(4 * w), nn.ReLU(inplace=True),
            nn.Conv2d(4 * w, 8 * w, 3, 2, 1, bias=False), _norm(8 * w),
        )
        self.low_to_high3 = nn.Sequential(nn.Conv2d(4 * w, high_ch, 1, bias=False), _norm(high_ch))
        self.low_to_high4 = nn.Sequential(nn.Conv2d(8 * w, high_ch, 1, bias=False), _norm(high_ch))
        self.dappm = _DAPPM(16 * w, dappm_width, 4 * w)
        self.head = _SegHead(4 * w, head_width, num_classes)
        self.aux_heads = nn.ModuleList([_SegHead(high_ch, head_width, num_classes)]) if aux_heads else None
        self._init_weights()

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor | tuple[torch.Tensor, list[torch.Tensor]]:
        f1 = self.stage1(self.stem(x))
        f2 = self.stage2(F.relu(f1))

        low = self.low3(F.relu(f2))
        high = self.high3(F.relu(f2))
        low, high = (
            low + self.high_to_low3(F.relu(high)),
            high + _resize(self.low_to_high3(F.relu(low)), high),
        )
        aux_input = high

        low = self.low4(F.relu(low))
        high = self.high4(F.relu(high))
        low, high = (
            low + self.high_to_low4(F.relu(high)),
            high + _resize(self.low_to_high4(F.relu(low)), high),
        )

        high = self.high5(F.relu(high))
        context = _resize(self.dappm(self.low5(F.relu(low))), high)
        logits = _resize(self.head(context + high), x)

        if not self.training or self.aux_heads is None:
            return logits
        return logits, [_resize(head(aux_input), x) for head in self.aux_heads]


class DDRNet23Slim(_DDRNet23):
    """DDRNet-23-slim (base width 32, 64-channel heads); 5.7M parameters on Cityscapes."""

    name = "ddrnet23_slim"
    output_stride = 32

    def __init__(self, num_classes: int = 3, aux_heads: bool = True, layer5_relu: bool = True) -> None:
        super().__init__(num_classes, aux_heads, width=32, head_width=64, layer5_relu=layer5_relu)


class DDRNet23(_DDRNet23):
    """DDRNet-23 (base width 64, 128-channel heads); 20.1M parameters on Cityscapes."""

    name = "ddrnet23"
    output_stride = 32

    def __init__(self, num_classes: int = 3, aux_heads: bool = True, layer5_relu: bool = True) -> None:
        super().__init__(num_classes, aux_heads, width=64, head_width=128, layer5_relu=layer5_relu)
