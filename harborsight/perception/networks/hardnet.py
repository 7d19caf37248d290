"""FC-HarDNet-70: a U-shaped segmentation network built from Harmonic Dense Blocks.

Chao, Kao, Ruan, Huang and Lin, "HarDNet: A Low Memory Traffic Network", ICCV 2019
(reference implementation: PingoLH/FCHarDNet).

A Harmonic Dense Block (HarDBlock) holds ``n`` conv-BN-ReLU 3x3 layers. Layer ``k``
(1-based; layer 0 is the block input) reads the concatenation of layers ``k - 2**j`` for
every power of two ``2**j`` dividing ``k``, and has ``g * m**(links - 1)`` channels (growth
rate ``g``, multiplier ``m = 1.7``, rounded to an even number). The block outputs the
concatenation of its odd layers and its last layer; the input is not passed through.

Encoder: a stem of four conv-BN-ReLU 3x3 layers (16, 24, 32, 48 channels; stride 2 in the
first and third, so 1/4 resolution), then five HarDBlocks with growth rates 10, 16, 18, 24,
32 and 4, 4, 8, 8, 8 layers. Each block is followed by a 1x1 conv-BN-ReLU to 64, 96, 160,
224, 320 channels and, except after the last, a 2x2 average pool, so the deepest block runs
at 1/64. The outputs of the first four blocks (before their 1x1 conv) are skips.

Decoder: four stages, deepest first. Each resizes its input bilinearly to the skip's size,
concatenates the skip, halves the channels with a 1x1 conv-BN-ReLU and applies a HarDBlock
with the same growth rate and depth as the encoder block at that resolution. A 1x1 conv
(with bias) gives class logits at 1/4, resized bilinearly to the input size.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

_STEM_WIDTHS = (16, 24, 32, 48)
_GROWTH_RATES = (10, 16, 18, 24, 32)
_BLOCK_DEPTHS = (4, 4, 8, 8, 8)
_TRANSITION_WIDTHS = (64, 96, 160, 224, 320)
_WIDTH_MULTIPLIER = 1.7


class _ConvBNReLU(nn.Sequential):
    """Bias-free square convolution with "same" padding, batch norm and ReLU."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int = 3, stride: int = 1) -> None:
        super().__init__(
            nn.Conv2d(in_ch, out_ch, kernel, stride=stride, padding=kernel // 2, bias=False),
            nn.BatchNorm2d(out_ch),
            nn.ReLU(inplace=True),
        )


def _harmonic_sources(index: int) -> tuple[int, ...]:
    """Earlier layers feeding layer ``index`` (>= 1): ``index - 2**j`` while ``2**j`` divides it.

    Nearest first; this is also the concatenation order of the layer's input.
    """
    sources = []
    step = 1
    while index % step == 0:
        sources.append(index - step)
        step *= 2
    return tuple(sources)


def _harmonic_width(num_sources: int, growth: int, multiplier: float) -> int:
    """Channels of a layer with ``num_sources`` inputs, rounded to an even count."""
    width = float(growth)
    for _ in range(num_sources - 1):
        width *= multiplier
    return 2 * int(int(width + 1) / 2)


class HarmonicDenseBlock(nn.Module):
    """HarDBlock: sparse harmonic concatenation links between conv-BN-ReLU 3x3 layers.

    The output is the concatenation (in layer order) of every odd layer and the last layer;
    :attr:`out_channels` gives its width.
    """

    def __init__(self, in_ch: int, growth: int, depth: int, multiplier: float = _WIDTH_MULTIPLIER) -> None:
        super().__init__()
        widths = [in_ch]
        sources: list[tuple[int, ...]] = []
        convs = []
        for index in range(1, depth + 1):
            links = _harmonic_sources(index)
            width = _harmonic_width(len(links), growth, multiplier)
            convs.append(_ConvBNReLU(sum(widths[k] for k in links), width))
            sources.append(links)
            widths.append(width)
        self.convs = nn.ModuleList(convs)
        self.sources = tuple(sources)
        self.kept = tuple(k for k in range(1, depth + 1) if k % 2 == 1 or k == depth)
        self.out_channels = sum(widths[k] for k in self.kept)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        layers = [x]
        for conv, links in zip(self.convs, self.sources, strict=True):
            inputs = [layers[k] for k in links]
            layers.append(conv(inputs[0] if len(inputs) == 1 else torch.cat(inputs, dim=1)))
        return torch.cat([layers[k] for k in self.kept], dim=1)


class _DecoderStage(nn.Module):
    """Upsample to the skip's size, concatenate it, halve channels with 1x1, then a HarDBlock."""

    def __init__(self, in_ch: int, skip_ch: int, growth: int, depth: int) -> None:
        super().__init__()
        fused = (in_ch + skip_ch) // 2
        self.squeeze = _ConvBNReLU(in_ch + skip_ch, fused, kernel=1)
        self.block = HarmonicDenseBlock(fused, growth, depth)
        self.out_channels = self.block.out_channels

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
        return self.block(self.squeeze(torch.cat([x, skip], dim=1)))


class FCHarDNet70(nn.Module):
    """FC-HarDNet-70 semantic segmentation network (no auxiliary heads).

    Args:
        num_classes: number of output classes.
        aux_heads: accepted for interface compatibility; FC-HarDNet has none, so
            :attr:`aux_heads` is always ``None`` and training mode returns plain logits.
    """

    name = "fchardnet70"
    # The deepest block runs at 1/64 (stem /4, then four 2x2 average pools); inputs padded to
    # multiples of 64 keep every pool exact (640x360 pads to 640x384 either way).
    output_stride = 64

    def __init__(self, num_classes: int = 3, aux_heads: bool = True) -> None:
        super().__init__()
        stem = []
        ch = 3
        for i, width in enumerate(_STEM_WIDTHS):
            stem.append(_ConvBNReLU(ch, width, stride=2 if i in (0, 2) else 1))
            ch = width
        self.stem = nn.Sequential(*stem)

        blocks = []
        transitions = []
        skip_widths = []
        last = len(_GROWTH_RATES) - 1
        for i, (growth, depth, width) in enumerate(
            zip(_GROWTH_RATES, _BLOCK_DEPTHS, _TRANSITION_WIDTHS, strict=True)
        ):
            block = HarmonicDenseBlock(ch, growth, depth)
            blocks.append(block)
            skip_widths.append(block.out_channels)
            transition: list[nn.Module] = [_ConvBNReLU(block.out_channels, width, kernel=1)]
            if i < last:
                transition.append(nn.AvgPool2d(kernel_size=2, stride=2))
            transitions.append(nn.Sequential(*transition))
            ch = width
        self.encoder_blocks = nn.ModuleList(blocks)
        self.encoder_transitions = nn.ModuleList(transitions)

        stages = []
        for i in reversed(range(last)):
            stage = _DecoderStage(ch, skip_widths[i], _GROWTH_RATES[i], _BLOCK_DEPTHS[i])
            stages.append(stage)
            ch = stage.out_channels
        self.decoder_stages = nn.ModuleList(stages)
        self.classifier = nn.Conv2d(ch, num_classes, kernel_size=1)
        self.aux_heads = None

        # As the reference training script: Xavier-normal conv weights, other parameters default.
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.xavier_normal_(module.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = self.stem(x)
        skips = []
        for block, transition in zip(self.encoder_blocks, self.encoder_transitions, strict=True):
            feats = block(feats)
            skips.append(feats)
            feats = transition(feats)
        # The deepest block's output is not a skip; decoder stages pair with the rest, deepest first.
        for stage, skip in zip(self.decoder_stages, reversed(skips[:-1]), strict=True):
            feats = stage(feats, skip)
        logits = self.classifier(feats)
        return F.interpolate(logits, size=x.shape[-2:], mode="bilinear", align_corners=False)
