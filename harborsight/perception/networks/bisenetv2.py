"""BiSeNet V2: a two-pathway real-time segmentation network.

Yu, Gao, Wang, Yu, Shen, Sang, "BiSeNet V2: Bilateral Network with Guided Aggregation for
Real-time Semantic Segmentation", International Journal of Computer Vision 129, 2021.
The layer layout follows the widely used CoinCheung/BiSeNet PyTorch implementation.

Layout (strides relative to the input image):

* Detail branch: wide and shallow plain 3x3 conv-BN-ReLU stages, 64 -> 64 -> 128 channels at
  strides 2, 4 and 8; it keeps the spatial detail.
* Semantic branch: narrow and deep. A stem (16 channels, stride 4) mixes a strided conv path with
  a max-pool path; gather-and-expand layers (depthwise convs with expansion ratio 6 and residual
  connections) give 32 channels at stride 8, 64 at stride 16 and 128 at stride 32; a context
  embedding block adds globally pooled context to the stride-32 map.
* Bilateral guided aggregation: each branch gates the other through sigmoid attention, once at
  stride 8 and once at stride 32, and the sum is fused by a 3x3 conv (128 channels, stride 8).
* Segment head: 3x3 conv to 1024 channels, dropout, 1x1 conv to the class logits, bilinear
  upsampling to the input size.
* Four auxiliary heads (training only, in ``aux_heads``) read the semantic branch at strides 4, 8,
  16 and 32 (after the stem, the second and third stage, and the last gather-and-expand layer).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["BiSeNetV2"]

_EXPANSION = 6


class _ConvBNReLU(nn.Sequential):
    """Bias-free convolution, batch norm and ReLU; the padding keeps "same" geometry."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1) -> None:
        super().__init__(
            nn.Conv2d(cin, cout, kernel, stride=stride, padding=kernel // 2, bias=False),
            nn.BatchNorm2d(cout),
            nn.ReLU(inplace=True),
        )


def _depthwise(cin: int, cout: int, stride: int = 1) -> nn.Conv2d:
    """3x3 depthwise (``cout`` a multiple of ``cin``) convolution without bias."""
    return nn.Conv2d(cin, cout, 3, stride=stride, padding=1, groups=cin, bias=False)


def _pointwise(cin: int, cout: int) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 1, bias=False)


class _DetailBranch(nn.Module):
    """Three stages of plain 3x3 convolutions, each halving the resolution: output stride 8."""

    def __init__(self) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        cin = 3
        for cout, depth in ((64, 2), (64, 3), (128, 3)):
            layers.append(_ConvBNReLU(cin, cout, 3, 2))
            layers += [_ConvBNReLU(cout, cout, 3) for _ in range(depth - 1)]
            cin = cout
        self.layers = nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        return self.layers(x)


class _Stem(nn.Module):
    """Stride-4 stem: a strided conv, then a conv path and a max-pool path joined and fused."""

    def __init__(self, width: int = 16) -> None:
        super().__init__()
        self.entry = _ConvBNReLU(3, width, 3, 2)
        half = width // 2
        self.conv_path = nn.Sequential(_ConvBNReLU(width, half, 1), _ConvBNReLU(half, width, 3, 2))
        self.pool_path = nn.MaxPool2d(3, stride=2, padding=1)
        self.merge = _ConvBNReLU(2 * width, width, 3)

    def forward(self, x: Tensor) -> Tensor:
        y = self.entry(x)
        return self.merge(torch.cat([self.conv_path(y), self.pool_path(y)], dim=1))


class _GatherExpand(nn.Module):
    """Gather-and-expand layer with an inverted-bottleneck body and a residual connection.

    With ``stride=1`` the body is 3x3 conv, depthwise 3x3 expansion (x6) and a 1x1 projection,
    added to the identity. With ``stride=2`` the depthwise expansion is strided and followed by a
    second depthwise 3x3 conv, and the shortcut is a strided depthwise 3x3 conv plus a 1x1 conv.
    The projection's batch norm starts with zero scale, so each layer starts as its shortcut.
    """

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        wide = cin * _EXPANSION
        body: list[nn.Module] = [_ConvBNReLU(cin, cin, 3)]
        body += [_depthwise(cin, wide, stride), nn.BatchNorm2d(wide)]
        shortcut: nn.Module = nn.Identity()
        if stride == 1:
            if cin != cout:
                raise ValueError("a stride-1 gather-and-expand layer keeps its channel count")
        else:
            body += [_depthwise(wide, wide), nn.BatchNorm2d(wide)]
            shortcut = nn.Sequential(
                _depthwise(cin, cin, stride), nn.BatchNorm2d(cin), _pointwise(cin, cout), nn.BatchNorm2d(cout)
            )
        body.append(nn.ReLU(inplace=True))
        self.body = nn.Sequential(*body)
        self.project = _pointwise(wide, cout)
        self.project_bn = nn.BatchNorm2d(cout)
        self.shortcut = shortcut
        self.act = nn.ReLU(inplace=True)

    def forward(self, x: Tensor) -> Tensor:
        y = self.project_bn(self.project(self.body(x)))
        return self.act(y + self.shortcut(x))


class _ContextEmbedding(nn.Module):
    """Global average pooling, batch norm and a 1x1 conv, broadcast-added, then a 3x3 conv."""

    def __init__(self, width: int = 128) -> None:
        super().__init__()
        self.pool_bn = nn.BatchNorm2d(width)
        self.squeeze = _ConvBNReLU(width, width, 1)
        self.fuse = _ConvBNReLU(width, width, 3)

    def forward(self, x: Tensor) -> Tensor:
        ctx = self.squeeze(self.pool_bn(x.mean(dim=(2, 3), keepdim=True)))
        return self.fuse(x + ctx)


class _SemanticBranch(nn.Module):
    """Stem plus gather-and-expand stages; returns the four auxiliary taps and the final map."""

    def __init__(self) -> None:
        super().__init__()
        self.stem = _Stem(16)
        self.stage3 = nn.Sequential(_GatherExpand(16, 32, 2), _GatherExpand(32, 32))
        self.stage4 = nn.Sequential(_GatherExpand(32, 64, 2), _GatherExpand(64, 64))
        self.stage5 = nn.Sequential(_GatherExpand(64, 128, 2), *[_GatherExpand(128, 128) for _ in range(3)])
        self.context = _ContextEmbedding(128)

    def forward(self, x: Tensor) -> tuple[list[Tensor], Tensor]:
        s4 = self.stem(x)
        s8 = self.stage3(s4)
        s16 = self.stage4(s8)
        s32 = self.stage5(s16)
        return [s4, s8, s16, s32], self.context(s32)


class _GuidedAggregation(nn.Module):
    """Bilateral guided aggregation of the stride-8 detail map and the stride-32 semantic map."""

    def __init__(self, width: int = 128) -> None:
        super().__init__()
        # detail features kept at stride 8, gated by upsampled semantic attention
        self.detail_keep = nn.Sequential(
            _depthwise(width, width), nn.BatchNorm2d(width), _pointwise(width, width)
        )
        # detail features brought down to stride 32
        self.detail_down = nn.Sequential(
            nn.Conv2d(width, width, 3, stride=2, padding=1, bias=False),
            nn.BatchNorm2d(width),
            nn.AvgPool2d(3, stride=2, padding=1),
        )
        # semantic attention for the stride-8 path
        self.semantic_gate = nn.Sequential(
            nn.Conv2d(width, width, 3, padding=1, bias=False),
            nn.BatchNorm2d(width),
        )
        # semantic features kept at stride 32, gating the downsampled detail features
        self.semantic_keep = nn.Sequential(
            _depthwise(width, width), nn.BatchNorm2d(width), _pointwise(width, width)
        )
        self.fuse = _ConvBNReLU(width, width, 3)

    def forward(self, detail: Tensor, semantic: Tensor) -> Tensor:
        size = detail.shape[-2:]
        gate_hi = F.interpolate(self.semantic_gate(semantic), size=size, mode="nearest")
        high = self.detail_keep(detail) * torch.sigmoid(gate_hi)
        low = self.detail_down(detail) * torch.sigmoid(self.semantic_keep(semantic))
        low = F.interpolate(low, size=size, mode="nearest")
        return self.fuse(high + low)


class _SegHead(nn.Module):
    """3x3 conv, dropout and a 1x1 classifier; upsampling to the input size is done by the caller.

    An auxiliary head (``refine=True``) first doubles the resolution (nearest) and applies a 3x3
    conv whose width is the square of the head's total upsampling factor, as in the reference.
    """

    def __init__(self, cin: int, mid: int, num_classes: int, up_factor: int, refine: bool) -> None:
        super().__init__()
        self.conv = _ConvBNReLU(cin, mid, 3)
        self.drop = nn.Dropout(0.1)
        self.refine: nn.Module | None = None
        width = mid
        if refine:
            width = up_factor * up_factor
            self.refine = _ConvBNReLU(mid, width, 3)
        self.classifier = nn.Conv2d(width, num_classes, 1, bias=True)

    def forward(self, x: Tensor) -> Tensor:
        y = self.drop(self.conv(x))
        if self.refine is not None:
            y = self.refine(F.interpolate(y, scale_factor=2.0, mode="nearest"))
        return self.classifier(y)


class BiSeNetV2(nn.Module):
    """BiSeNet V2 with optional training-only auxiliary heads (see the module docstring)."""

    name = "bisenetv2"
    output_stride = 32

    def __init__(self, num_classes: int = 3, aux_heads: bool = True) -> None:
        super().__init__()
        self.num_classes = num_classes
        self.detail = _DetailBranch()
        self.semantic = _SemanticBranch()
        self.aggregate = _GuidedAggregation(128)
        self.head = _SegHead(128, 1024, num_classes, up_factor=8, refine=False)
        self.aux_heads: nn.ModuleList | None = None
        if aux_heads:
            taps = [(16, 4), (32, 8), (64, 16), (128, 32)]
            self.aux_heads = nn.ModuleList(
                [_SegHead(cin, 128, num_classes, up_factor=f, refine=True) for cin, f in taps]
            )
        self._init_weights()

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.Linear)):
                nn.init.kaiming_normal_(m.weight, mode="fan_out")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for m in self.modules():
            if isinstance(m, _GatherExpand):
                nn.init.zeros_(m.project_bn.weight)

    def forward(self, x: Tensor) -> Tensor | tuple[Tensor, list[Tensor]]:
        size = x.shape[-2:]
        taps, semantic = self.semantic(x)
        fused = self.aggregate(self.detail(x), semantic)
        logits = F.interpolate(self.head(fused), size=size, mode="bilinear", align_corners=False)
        if not self.training or self.aux_heads is None:
            return logits
        aux = [
            F.interpolate(head(tap), size=size, mode="bilinear", align_corners=False)
            for head, tap in zip(self.aux_heads, taps, strict=True)
        ]
        return logits, aux
