"""A network plus the pre- and post-processing every caller must get right.

``SegmentationModel`` takes uint8 BGR images ``(N, H, W, 3)`` — what OpenCV reads — and
returns logits ``(N, C, H, W)`` at the same size:

    x = (RGB(image) / 255 - mean) / std            (ImageNet statistics)
    x = pad x on the right/bottom to multiples of the network's output stride (zeros, i.e.
        the mean colour after normalisation; 360 rows become 384 for stride 32)
    logits = network(x)[..., :H, :W]

Exported as one ONNX graph, so ONNX Runtime callers get the same numbers as torch.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from harborsight.perception.classes import RGB_MEAN, RGB_STD


class SegmentationModel(nn.Module):
    def __init__(self, network: nn.Module) -> None:
        super().__init__()
        self.network = network
        self.output_stride = int(network.output_stride)
        self.register_buffer("mean", torch.tensor(RGB_MEAN).view(1, 3, 1, 1) * 255.0)
        self.register_buffer("std", torch.tensor(RGB_STD).view(1, 3, 1, 1) * 255.0)

    def preprocess(self, images_bgr: torch.Tensor) -> torch.Tensor:
        """uint8 (N, H, W, 3) BGR -> normalised float (N, 3, H', W'), H', W' padded."""
        if images_bgr.ndim != 4 or images_bgr.shape[-1] != 3:
            raise ValueError(f"expected (N, H, W, 3) BGR images, got shape {tuple(images_bgr.shape)}")
        x = images_bgr.permute(0, 3, 1, 2).float().flip(1)  # BGR -> RGB
        x = (x - self.mean) / self.std
        h, w = images_bgr.shape[1], images_bgr.shape[2]
        pad_h = (-h) % self.output_stride
        pad_w = (-w) % self.output_stride
        return F.pad(x, (0, pad_w, 0, pad_h))

    def forward(self, images_bgr: torch.Tensor):
        """Logits at the input size; in training with aux heads, ``(logits, [aux, ...])``."""
        h, w = images_bgr.shape[1], images_bgr.shape[2]
        out = self.network(self.preprocess(images_bgr))
        if isinstance(out, tuple):
            main, aux = out
            return main[..., :h, :w], [a[..., :h, :w] for a in aux]
        return out[..., :h, :w]


class _ExportGraph(nn.Module):
    """Adds the class map's ``labels`` (uint8 argmax) as a second output."""

    def __init__(self, model: SegmentationModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, images_bgr: torch.Tensor):
        logits = self.model(images_bgr)
        return logits, logits.argmax(dim=1).to(torch.uint8)


class TorchSegmenter:
    """``segment(image_bgr) -> labels`` for a :class:`SegmentationModel`, like
    :class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter` but at the frame's own size
    (the model pads and crops inside). The caller chooses train/eval mode; fp16 autocast when
    ``amp`` and the device is CUDA."""

    def __init__(self, model: SegmentationModel, device: str | torch.device = "cpu",
                 amp: bool = False) -> None:
        self.model = model
        self.device = torch.device(device)
        self.amp = amp and self.device.type == "cuda"

    def logits(self, image_bgr) -> torch.Tensor:
        """Float logits (C, H, W) on the model's device."""
        batch = torch.from_numpy(image_bgr[None]).to(self.device)
        with torch.inference_mode(), torch.autocast(self.device.type, torch.float16,
                                                    enabled=self.amp):
            return self.model(batch)[0].float()

    def segment(self, image_bgr):
        """uint8 class labels (H, W) as a numpy array."""
        return self.logits(image_bgr).argmax(0).to(torch.uint8).cpu().numpy()
