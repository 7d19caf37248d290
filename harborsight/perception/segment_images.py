"""Label masks for image files of any size and aspect (``harborsight segment``): numpy, OpenCV
and ONNX Runtime, no torch.

A harborsight ONNX model takes a fixed input (640x360 for the default model). Two ways to
run it on a frame of another size:

``resize``
    The frame is stretched to the model input, and the logits are resized back to the frame
    bilinearly (pixel centres aligned) before the argmax: :meth:`OnnxSegmenter.segment`. One
    model call per frame; a 4000x3000 still is shrunk 6.25x across and 8.3x down, so small
    objects get few model pixels and the aspect ratio changes.

``tiles``
    The frame is first scaled by ``tile_scale`` (1.0: not scaled), capped so that its longer
    side is at most ``max_side`` pixels, so that a pixel covers about as much of the scene as
    in the training frames. Where the scaled frame is smaller than a window it is padded to
    one window, centred, by edge reflection (``numpy.pad(mode="reflect")``: the model sees
    plausible water and quay on all sides at the same pixel scale, and the padding's labels
    are dropped). It is then cut into windows of the model input that overlap by at least
    ``tile_overlap`` of a window in each direction, evenly spaced, the first at the top-left
    corner and the last flush with the right and bottom edges, so that any size is covered
    exactly. Each window's logits ``(C, h, w)`` are added into a float32 accumulator of the
    scaled frame's size, weighted by a separable tent that is highest in the window's middle
    and falls toward its edges (``1/n`` at the outermost pixel of an ``n``-pixel side, never
    0), where a model sees the least context; the sum is divided by the summed weights. The
    blended logits are then resized to the frame (bilinear when enlarging, area average when
    shrinking) and argmaxed. Windows go to the model in batches when its input's first
    dimension is free, one by one when it is fixed to 1 (every ``harborsight export`` so far).
    Memory: the accumulator is ``C x H x W`` float32 at the scaled size, 144 MB for a
    4000x3000 frame at scale 1.

The masks are single-channel uint8 PNGs at each image's own size: 0 water, 1 ship,
2 obstacle (:mod:`harborsight.perception.classes`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from harborsight.errors import HarborsightError, InputError
from harborsight.files import natural_key, strict_json, write_bytes_atomic, write_text_atomic
from harborsight.perception.classes import (
    CLASS_NAMES,
    IGNORE,
    NUM_CLASSES,
    OBSTACLE,
    SHIP,
    WATER,
)
from harborsight.perception.flips import flip_views

if TYPE_CHECKING:  # onnxruntime is imported by the commands that run a model
    from harborsight.perception.onnx_segmenter import OnnxSegmenter

#: suffixes a folder is scanned for (any letter case); a file named on its own is tried
#: whatever its suffix
IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".tif", ".tiff"})

#: overlay colours (BGR) from the Okabe-Ito palette, told apart with the common colour-vision
#: deficiencies: water blue #0072B2, ship vermillion #D55E00, obstacle yellow #F0E442
OVERLAY_COLOURS_BGR = {WATER: (178, 114, 0), SHIP: (0, 94, 213), OBSTACLE: (66, 228, 240)}
#: weight of the class colour in the overlay
OVERLAY_ALPHA = 0.45
#: JPEG quality of the overlays
OVERLAY_JPEG_QUALITY = 90

SCHEMA = "harborsight.segment/1"


class SegmentMode(StrEnum):
    """How a frame of another size than the model input is segmented (module docstring)."""

    resize = "resize"
    tiles = "tiles"
    auto = "auto"


@dataclass(frozen=True)
class SegmentOptions:
    """The mode and its parameters; ``tile_*``, ``max_side`` and ``batch_size`` act in
    ``tiles`` mode only. ``batch_size``: windows per model call when the model's batch
    dimension is free (a fixed batch dimension wins). ``flips``: test-time flips in every
    mode (:data:`~harborsight.perception.flips.FLIP_VIEWS`)."""

    mode: SegmentMode = SegmentMode.resize
    tile_overlap: float = 0.25
    tile_scale: float = 1.0
    max_side: int | None = None
    batch_size: int = 4
    flips: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", SegmentMode(self.mode))
        if not 0.0 <= self.tile_overlap <= 0.9:
            raise InputError(None, "--tile-overlap", f"expected a fraction of a window in "
                             f"[0, 0.9], got {self.tile_overlap}")
        if not (self.tile_scale > 0 and math.isfinite(self.tile_scale)):
            raise InputError(None, "--tile-scale", f"expected a factor > 0, got {self.tile_scale}")
        if self.max_side is not None and self.max_side < 1:
            raise InputError(None, "--max-side", f"expected pixels >= 1, got {self.max_side}")
        if self.batch_size < 1:
            raise InputError(None, "batch_size", f"expected >= 1, got {self.batch_size}")
        flip_views(self.flips)

    @classmethod
    def from_options(cls, mode: str | SegmentMode = SegmentMode.resize,
                     tile_overlap: float | None = None, tile_scale: float | None = None,
                     max_side: int | None = None, flips: int = 1) -> SegmentOptions:
        """From command-line options, where ``None`` is "not given": a tiles option with
        ``resize`` is refused rather than silently ignored."""
        mode = SegmentMode(mode)
        given = {"--tile-overlap": tile_overlap, "--tile-scale": tile_scale, "--max-side": max_side}
        if mode is not SegmentMode.tiles:
            for name, value in given.items():
                if value is not None:
                    raise InputError(None, name, f"{name} is for --mode tiles ({mode.value} "
                                     "chooses for itself how a frame meets the model input)")
            return cls(mode, flips=flips)
        return cls(SegmentMode.tiles, 0.25 if tile_overlap is None else tile_overlap,
                   1.0 if tile_scale is None else tile_scale, max_side, flips=flips)

    def to_dict(self) -> dict:
        flips = {"flips": self.flips} if self.flips != 1 else {}
        if self.mode is not SegmentMode.tiles:
            return {"mode": self.mode.value, **flips}
        return {"mode": "tiles", "tile_overlap": self.tile_overlap, "tile_scale": self.tile_scale,
                "max_side": self.max_side, **flips}

    def describe(self) -> str:
        cap = f", longer side at most {self.max_side} px" if self.max_side else ""
        flips = {1: "", 2: "; with its mirror image", 4: "; with its mirror images"}[self.flips]
        if self.mode is SegmentMode.resize:
            return f"resize (each frame stretched to the model input{flips})"
        if self.mode is SegmentMode.auto:
            return ("auto (frames no larger than the model input enlarged without stretching "
                    f"to fill one window, larger ones stretched into it{flips})")
        return (f"tiles (frame scaled x{self.tile_scale:g}{cap}, windows overlapping by "
                f"{self.tile_overlap:g}{flips})")


# --- finding images -------------------------------------------------------------------------

def collect_images(inputs: Sequence[str | Path], recursive: bool = False,
                   names: dict[Path, str] | None = None) -> list[Path]:
    """The image files named or found in ``inputs``, in the order given; a folder adds its
    ``IMAGE_SUFFIXES`` files (any letter case; not hidden ones; with ``recursive`` those of its
    subfolders too) in natural order. A file named twice is taken once. A missing path, or
    no image at all, is an :class:`InputError`. ``names`` (filled when given) maps a file
    found in a subfolder to its mask's name there (``101MEDIA/DJI_0001``): a drone restarts
    its numbering in each folder."""
    found: list[Path] = []
    seen: set[Path] = set()
    for given in inputs:
        path = Path(given)
        if path.is_dir():
            pattern = path.rglob("*") if recursive else path.iterdir()
            files = [p for p in pattern if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
                     and not any(part.startswith(".") for part in p.relative_to(path).parts)]
            files.sort(key=lambda p: [natural_key(part) for part in p.relative_to(path).parts])
        elif path.exists():
            files = [path]
        else:
            raise InputError(path, None, "no such file or folder")
        for file in files:
            key = file.resolve()
            if key not in seen:
                seen.add(key)
                found.append(file)
                if names is not None and path.is_dir() and len(file.relative_to(path).parts) > 1:
                    names[file] = file.relative_to(path).with_suffix("").as_posix()
    if not found:
        where = ", ".join(str(p) for p in inputs) or "(no input)"
        suffixes = ", ".join(sorted(IMAGE_SUFFIXES))
        raise InputError(where, None, f"no image files ({suffixes}) found"
                         + ("" if recursive else "; --recursive also searches subfolders"))
    return found


# --- tiling ---------------------------------------------------------------------------------

def tile_starts(length: int, window: int, overlap: float) -> list[int]:
    """Start offsets of windows of ``window`` pixels covering ``length`` pixels, neighbours
    overlapping by at least ``overlap`` of a window, evenly spaced, the first at 0 and the last
    at ``length - window``. One window at 0 when ``length <= window``."""
    if length <= window:
        return [0]
    stride = max(window * (1.0 - overlap), 1.0)
    count = math.ceil((length - window) / stride - 1e-9) + 1
    return [round(k * (length - window) / (count - 1)) for k in range(count)]


def tent_weights(height: int, width: int) -> np.ndarray:
    """float32 ``(height, width)`` blending weight of a window: the product of two tents,
    ``1 - |2 (i + 0.5) / n - 1|`` along each side of ``n`` pixels, highest in the middle and
    ``1/n`` at the edge pixels (never 0, so every covered pixel has a positive weight)."""
    def tent(n: int) -> np.ndarray:
        i = np.arange(n, dtype=np.float64)
        return 1.0 - np.abs(2.0 * (i + 0.5) / n - 1.0)

    return np.outer(tent(height), tent(width)).astype(np.float32)


def processing_size(width: int, height: int, scale: float, max_side: int | None) -> tuple[int, int]:
    """(width, height) a frame is scaled to before tiling: ``scale`` times, reduced so that
    the longer side is at most ``max_side``."""
    if max_side is not None and max(width, height) * scale > max_side:
        scale = max_side / max(width, height)
    return max(1, round(width * scale)), max(1, round(height * scale))


def tiled_logits(image_bgr: np.ndarray, run: Callable[[np.ndarray], np.ndarray],
                 window_hw: tuple[int, int], overlap: float, batch: int = 1,
                 on_windows: Callable[[int], None] | None = None) -> np.ndarray:
    """Blended float32 logits ``(C, H, W)`` of an image (already at the processing scale):
    windows of ``window_hw`` (padded by reflection where the image is smaller), ``run(batch
    (N, h, w, 3) uint8) -> (N, C, h, w)`` on up to ``batch`` windows at a time, each weighted
    by :func:`tent_weights` and normalised by the summed weights. ``on_windows(n)`` is told
    the number of windows."""
    h, w = image_bgr.shape[:2]
    win_h, win_w = window_hw
    top, left = max(0, win_h - h) // 2, max(0, win_w - w) // 2
    if h < win_h or w < win_w:
        image_bgr = np.pad(image_bgr, ((top, max(0, win_h - h) - top),
                                       (left, max(0, win_w - w) - left), (0, 0)), mode="reflect")
    ph, pw = image_bgr.shape[:2]
    corners = [(y, x) for y in tile_starts(ph, win_h, overlap) for x in tile_starts(pw, win_w, overlap)]
    if on_windows:
        on_windows(len(corners))
    weights = tent_weights(win_h, win_w)
    weight_sum = np.zeros((ph, pw), np.float32)
    accumulator: np.ndarray | None = None
    for first in range(0, len(corners), batch):
        group = corners[first:first + batch]
        windows = np.stack([image_bgr[y:y + win_h, x:x + win_w] for y, x in group])
        logits = run(windows)
        if logits.shape[0] != len(group) or logits.shape[2:] != (win_h, win_w):
            raise ValueError(f"model returned logits {logits.shape} for windows {windows.shape}")
        if accumulator is None:
            accumulator = np.zeros((logits.shape[1], ph, pw), np.float32)
        for (y, x), window_logits in zip(group, logits, strict=True):
            accumulator[:, y:y + win_h, x:x + win_w] += window_logits * weights
            weight_sum[y:y + win_h, x:x + win_w] += weights
    assert accumulator is not None
    accumulator = accumulator[:, top:top + h, left:left + w]
    accumulator /= weight_sum[top:top + h, left:left + w]
    return accumulator


def labels_from_logits(logits: np.ndarray, width: int, height: int) -> np.ndarray:
    """uint8 argmax ``(height, width)`` of logits ``(C, h, w)`` resized to the frame one class
    at a time (bilinear, pixel centres aligned, when enlarging; area average when shrinking),
    keeping only a running maximum: no ``C x H x W`` copy at the frame size. Ties go to the
    lower class, as with ``argmax``."""
    h, w = logits.shape[1:]
    interpolation = cv2.INTER_AREA if width * height < w * h else cv2.INTER_LINEAR

    def channel(c: int) -> np.ndarray:
        if (h, w) == (height, width):
            return logits[c]
        return cv2.resize(np.ascontiguousarray(logits[c]), (width, height),
                          interpolation=interpolation)

    best = channel(0).copy()
    labels = np.zeros((height, width), np.uint8)
    for c in range(1, logits.shape[0]):
        values = channel(c)
        higher = values > best
        best[higher] = values[higher]
        labels[higher] = c
    return labels


# --- running a model ------------------------------------------------------------------------

def model_batch(segmenter: OnnxSegmenter) -> int | None:
    """The fixed batch size of the model's input, or None when it is free."""
    dim = segmenter.session.get_inputs()[0].shape[0]
    return dim if isinstance(dim, int) and dim > 0 else None


def _window_runner(segmenter: OnnxSegmenter, flips: int = 1) -> Callable[[np.ndarray], np.ndarray]:
    """``run(windows) -> logits`` feeding the model at its fixed batch size (the last group
    filled with copies of its last window) or all at once when the batch is free; with
    test-time ``flips`` (:meth:`OnnxSegmenter.batch_logits`)."""
    fixed = model_batch(segmenter)

    def run(windows: np.ndarray) -> np.ndarray:
        if fixed is None:
            return segmenter.batch_logits(windows, flips)
        parts = []
        for start in range(0, len(windows), fixed):
            part = windows[start:start + fixed]
            n = len(part)
            if n < fixed:
                part = np.concatenate([part, np.repeat(part[-1:], fixed - n, axis=0)])
            parts.append(segmenter.batch_logits(part, flips)[:n])
        return np.concatenate(parts)

    return run


def small_frame_logits(segmenter: OnnxSegmenter, image_bgr: np.ndarray, flips: int = 1
                       ) -> np.ndarray | None:
    """Logits ``(C, h, w)`` over a frame no larger than the model input, as ``auto`` makes
    them (:func:`auto_options`: enlarged without stretching, padded into one window), on a
    grid that covers the frame exactly; None for any other frame (``auto`` stretches it).
    The measuring pipelines read a small frame's labels and probabilities from these, so
    that they segment it as ``segment`` does."""
    options = auto_options(segmenter, image_bgr)
    height, width = image_bgr.shape[:2]
    if (options.mode is not SegmentMode.tiles
            or (height, width) == (segmenter.input_height, segmenter.input_width)):
        return None
    return scaled_tile_logits(segmenter, image_bgr, replace(options, flips=flips))


def scaled_tile_logits(segmenter: OnnxSegmenter, image_bgr: np.ndarray, options: SegmentOptions,
                        info: dict | None = None) -> np.ndarray:
    """Logits ``(C, h, w)`` of a frame in ``tiles`` mode, on the grid of the frame scaled by
    ``options`` (module docstring); ``info``, if given, receives ``windows`` and the
    ``processed`` (width, height)."""
    height, width = image_bgr.shape[:2]
    pw, ph = processing_size(width, height, options.tile_scale, options.max_side)
    scaled = image_bgr
    if (pw, ph) != (width, height):
        shrink = pw * ph < width * height
        scaled = cv2.resize(image_bgr, (pw, ph),
                            interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    fixed = model_batch(segmenter)
    counted: list[int] = []
    logits = tiled_logits(scaled, _window_runner(segmenter, options.flips),
                          (segmenter.input_height, segmenter.input_width), options.tile_overlap,
                          fixed or options.batch_size, counted.append)
    if info is not None:
        info.update(windows=counted[0], processed=[pw, ph])
    return logits


def segment_tiles(segmenter: OnnxSegmenter, image_bgr: np.ndarray, options: SegmentOptions,
                  info: dict | None = None) -> np.ndarray:
    """uint8 labels (H, W) of a frame in ``tiles`` mode (module docstring). ``info``, if
    given, receives ``windows`` and the ``processed`` (width, height)."""
    if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
        raise ValueError(f"expected a uint8 BGR image (H, W, 3), got {image_bgr.shape} "
                         f"{image_bgr.dtype}")
    height, width = image_bgr.shape[:2]
    return labels_from_logits(scaled_tile_logits(segmenter, image_bgr, options, info), width, height)


def segment_labels(segmenter: OnnxSegmenter, image_bgr: np.ndarray, options: SegmentOptions,
                   info: dict | None = None) -> np.ndarray:
    """uint8 labels (H, W) at the frame's own size, in the mode of ``options``."""
    if options.mode is SegmentMode.auto:
        options = replace(auto_options(segmenter, image_bgr), flips=options.flips)
    if options.mode is SegmentMode.tiles:
        return segment_tiles(segmenter, image_bgr, options, info)
    if info is not None:
        info.update(windows=1, processed=[segmenter.input_width, segmenter.input_height])
    return segmenter.segment(image_bgr, options.flips)


def segment_function(segmenter: OnnxSegmenter, options: SegmentOptions
                     ) -> Callable[[np.ndarray], np.ndarray]:
    """``segment(image) -> labels`` in the mode of ``options`` (for the evaluation loops)."""
    if options.mode is SegmentMode.resize:
        return lambda image: segmenter.segment(image, options.flips)
    if options.mode is SegmentMode.auto:
        return lambda image: segment_labels(segmenter, image, options)
    return lambda image: segment_tiles(segmenter, image, options)


def auto_options(segmenter: OnnxSegmenter, image_bgr: np.ndarray) -> SegmentOptions:
    """What ``auto`` does with one frame. A frame no larger than the model input in either
    dimension is enlarged uniformly until it fills the input in one dimension (scale
    ``min(H_in / h, W_in / w)``, no stretch: a 256x256 marina tile becomes 360x360 for a
    640x360 model) and padded into one window (``tiles`` at that scale); a larger one is
    stretched into the input (``resize``). The enlargement gives thin structures (pontoons,
    finger piers 3-8 px wide at 0.3 m/px) more of the network's 1/8-scale output cells.
    Measured on the marina val split (20 tiles, 2026-11-26 labels): a fine-tune of the
    default model 61.2 % mIoU enlarged against 57.9 % at the tile's own scale (the obstacle
    IoU 18.0 against 11.5 %), the shipped model 53.6 against 53.5 %; enlarging 2x gave 60.0
    and 50.5 %. A larger frame loses little by shrinking and stretching: lake-shore photos
    (1024x768) 69.9 % stretched against 67.8 % as scale-1 tiles (docs/results.md, "Real
    frames")."""
    height, width = image_bgr.shape[:2]
    if height <= segmenter.input_height and width <= segmenter.input_width:
        scale = min(segmenter.input_height / height, segmenter.input_width / width)
        return SegmentOptions(SegmentMode.tiles, tile_scale=scale)
    return SegmentOptions(SegmentMode.resize)


def model_summary(segmenter: OnnxSegmenter) -> dict:
    """What ``segment.json`` says about the model: file, network, input, batch, the held-out
    scores of its sidecar (None where it has none) and, for an int8 model, how its
    convolutions ran (:func:`~harborsight.perception.onnx_segmenter.int8_arithmetic`:
    ``reference``, ``fused (vnni)``, or ``fused, uint8 weights (avx2 without vnni)``)."""
    from harborsight.perception.default_model import describe

    sidecar, metadata = segmenter.sidecar, segmenter.metadata
    heldout = sidecar.get("heldout") or {}
    return {
        "path": str(segmenter.path),
        "network": sidecar.get("network") or metadata.get("network"),
        "precision": sidecar.get("precision"),
        "input": {"width": segmenter.input_width, "height": segmenter.input_height},
        "batch": model_batch(segmenter) or "free",
        "heldout_miou": heldout.get("miou"),
        "heldout_frames": heldout.get("frames"),
        "heldout_data": heldout.get("data"),
        "meets_target": sidecar.get("meets_target"),
        "int8_arithmetic": segmenter.int8_arithmetic(),
        "description": describe(segmenter),
    }


# --- pictures -------------------------------------------------------------------------------

def class_fractions(labels: np.ndarray) -> dict[str, float]:
    """Share of the pixels of each class."""
    counts = np.bincount(labels.ravel(), minlength=NUM_CLASSES)[:NUM_CLASSES]
    return {name: float(n) / max(labels.size, 1) for name, n in zip(CLASS_NAMES, counts, strict=True)}


def overlay_image(image_bgr: np.ndarray, labels: np.ndarray,
                  fractions: dict[str, float] | None = None) -> np.ndarray:
    """The image blended with the class colours (:data:`OVERLAY_COLOURS_BGR`) and a legend in
    the top-left corner (class names, with their share of the pixels when ``fractions`` is
    given); no legend where the image is too small to hold it."""
    lut = np.zeros((256, 3), np.uint8)
    for class_id, colour in OVERLAY_COLOURS_BGR.items():
        lut[class_id] = colour
    picture = cv2.addWeighted(image_bgr, 1.0 - OVERLAY_ALPHA, lut[labels], OVERLAY_ALPHA, 0.0)
    _draw_legend(picture, fractions)
    return picture


def _draw_legend(picture: np.ndarray, fractions: dict[str, float] | None) -> None:
    height, width = picture.shape[:2]
    s = min(max(min(height, width) / 1000.0, 0.35), 4.0)
    font, font_scale, thickness = cv2.FONT_HERSHEY_SIMPLEX, 0.7 * s, max(1, round(2 * s))
    texts = [f"{name} {100 * fractions[name]:.1f} %" if fractions else name
             for name in CLASS_NAMES]
    sizes = [cv2.getTextSize(t, font, font_scale, thickness)[0] for t in texts]
    line_h = max(th for _, th in sizes)
    pad, margin = max(2, round(8 * s)), max(2, round(10 * s))
    box_w = 3 * pad + line_h + max(tw for tw, _ in sizes)
    box_h = pad + len(texts) * (line_h + pad)
    if box_w + 2 * margin > width or box_h + 2 * margin > height:
        return
    x0, y0 = margin, margin
    region = picture[y0:y0 + box_h, x0:x0 + box_w]
    region[:] = (region * 0.3).astype(np.uint8)
    for k, (text, class_id) in enumerate(zip(texts, (WATER, SHIP, OBSTACLE), strict=True)):
        top = y0 + pad + k * (line_h + pad)
        cv2.rectangle(picture, (x0 + pad, top), (x0 + pad + line_h, top + line_h),
                      OVERLAY_COLOURS_BGR[class_id], thickness=-1)
        cv2.putText(picture, text, (x0 + 2 * pad + line_h, top + line_h), font, font_scale,
                    (255, 255, 255), thickness, cv2.LINE_AA)


def _encode(suffix: str, picture: np.ndarray, params: Sequence[int] = ()) -> bytes:
    ok, data = cv2.imencode(suffix, picture, list(params))
    if not ok:
        raise OSError(f"OpenCV could not encode a {suffix} picture")
    return data.tobytes()


# --- the command's work ---------------------------------------------------------------------

@dataclass
class SegmentedImage:
    """One image's outputs; ``time_ms`` is the segmentation alone (model, blending, resize,
    argmax), without reading and writing files."""

    input: Path
    width: int
    height: int
    mask: Path
    overlay: Path | None
    fractions: dict[str, float]
    time_ms: float
    windows: int
    processed_wh: tuple[int, int]
    #: share of the pixels without a picture (alpha 0), labelled 255
    no_data_fraction: float = 0.0

    def to_dict(self) -> dict:
        return {"input": str(self.input), "width": self.width, "height": self.height,
                "mask": str(self.mask), "overlay": None if self.overlay is None else str(self.overlay),
                "fractions": self.fractions, "time_ms": round(self.time_ms, 3),
                "windows": self.windows, "processed_wh": list(self.processed_wh),
                "no_data_fraction": round(self.no_data_fraction, 6)}


@dataclass
class SegmentRun:
    out_dir: Path
    json_path: Path
    images: list[SegmentedImage] = field(default_factory=list)
    #: ``(input path, reason)`` of each image left out
    skipped: list[tuple[str, str]] = field(default_factory=list)


def segment_images(paths: Iterable[Path], segmenter: OnnxSegmenter, out_dir: str | Path,
                   options: SegmentOptions | None = None, overlay: bool = False,
                   on_image: Callable[[Path], None] | None = None,
                   names: dict[Path, str] | None = None) -> SegmentRun:
    """Write ``out_dir/<stem>.png`` (uint8 labels at the image's size) for each image, with
    ``overlay`` also ``out_dir/overlays/<stem>.jpg``, and ``out_dir/segment.json``; all
    atomically; an image in ``names`` (:func:`collect_images`) is written under that name
    (its subfolder mirrored). An image that cannot be read or written, whose name an earlier
    image's mask already took, or whose mask or overlay would replace one of the input
    images, is left out with the reason; the rest are still written. ``on_image(path)``
    after each image."""
    from harborsight.images import read_image_and_no_data

    options = options or SegmentOptions()
    paths = list(paths)
    out_dir = Path(out_dir)
    overlay_dir = out_dir / "overlays"
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        if overlay:
            overlay_dir.mkdir(exist_ok=True)
    except OSError as exc:
        raise InputError(out_dir, "--out", f"cannot create the output folder: {exc}") from None
    inputs = {p.resolve() for p in paths}
    run = SegmentRun(out_dir, out_dir / "segment.json")
    taken: dict[str, Path] = {}
    for path in paths:
        try:
            run.images.append(_segment_one(path, segmenter, options, out_dir,
                                           overlay_dir if overlay else None, inputs, taken,
                                           read_image_and_no_data,
                                           (names or {}).get(path, path.stem)))
        except (HarborsightError, OSError, cv2.error) as exc:
            reason = exc.message if isinstance(exc, InputError) else " ".join(str(exc).split())
            run.skipped.append((str(path), reason))
        if on_image:
            on_image(path)
    document = {
        "schema": SCHEMA,
        "model": model_summary(segmenter),
        "mode": {**options.to_dict(),
                 "window": {"width": segmenter.input_width, "height": segmenter.input_height}},
        "classes": {str(i): name for i, name in enumerate(CLASS_NAMES)},
        "time_ms_definition": "segmentation alone: model, blending, resize and argmax; "
                              "not reading or writing files",
        "images": [image.to_dict() for image in run.images],
        "skipped": [{"input": path, "reason": reason} for path, reason in run.skipped],
    }
    write_text_atomic(run.json_path, strict_json(document, indent=2) + "\n")
    return run


def _segment_one(path: Path, segmenter: OnnxSegmenter, options: SegmentOptions, out_dir: Path,
                 overlay_dir: Path | None, inputs: set[Path], taken: dict[str, Path],
                 read_picture: Callable[[Path], tuple[np.ndarray, np.ndarray | None]],
                 stem: str) -> SegmentedImage:
    mask_path = out_dir / f"{stem}.png"
    overlay_path = None if overlay_dir is None else overlay_dir / f"{stem}.jpg"
    if stem in taken:
        raise InputError(path, None, f"same name as {taken[stem]}: its mask {mask_path} "
                         "would be overwritten (rename one of them)")
    for output in (mask_path, overlay_path):
        if output is not None and output.resolve() in inputs:
            raise InputError(path, None, f"its output {output} is one of the input images; "
                             "choose another --out folder")
    image, no_data = read_picture(path)
    height, width = image.shape[:2]
    for output in (mask_path, overlay_path):
        if output is not None:
            output.parent.mkdir(parents=True, exist_ok=True)
    info: dict = {}
    start = time.perf_counter()
    labels = segment_labels(segmenter, image, options, info)
    if no_data is not None:          # no picture there: not seen, whatever the model says
        labels[no_data] = IGNORE
    elapsed_ms = 1000.0 * (time.perf_counter() - start)
    fractions = class_fractions(labels)
    write_bytes_atomic(mask_path, _encode(".png", labels))
    taken[stem] = path
    if overlay_path is not None:
        try:
            write_bytes_atomic(overlay_path, _encode(
                ".jpg", overlay_image(image, labels, fractions),
                (cv2.IMWRITE_JPEG_QUALITY, OVERLAY_JPEG_QUALITY)))
        except (OSError, cv2.error) as exc:
            raise InputError(path, None, f"mask written to {mask_path}, but not the overlay: "
                             + " ".join(str(exc).split())) from None
    return SegmentedImage(path, width, height, mask_path, overlay_path, fractions, elapsed_ms,
                          info["windows"], tuple(info["processed"]),
                          0.0 if no_data is None else float(no_data.mean()))
