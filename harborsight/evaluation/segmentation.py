"""Segmentation accuracy and speed, in the shape of the paper's Table II.

From the confusion matrix ``M[t, p]`` (pixels of true class ``t`` predicted as ``p``; pixels
labelled 255 are left out), per class ``c``:

    accuracy_c = M[c, c] / Σ_p M[c, p]                      (recall of class c)
    IoU_c      = M[c, c] / (Σ_p M[c, p] + Σ_t M[t, c] - M[c, c])

*Mean accuracy* is the average of ``accuracy_c`` over the classes present in the labels (the
"mean class accuracy" of FCN, Long et al. 2015; we read the paper's Table II "Mean accuracy"
as this). *Pixel accuracy* ``trace(M) / ΣM`` is reported beside it in the JSON. *mIoU* is the
average of ``IoU_c`` over classes that occur in the labels or the predictions. Speed is
end-to-end ``segment()`` calls per second on one frame at the dataset's resolution, batch 1,
after a warm-up, including any resize to a fixed-size ONNX model's input.

The paper's "Unknown" class is harborsight's ``obstacle``.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Hashable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from harborsight.errors import HarborsightError, InputError
from harborsight.evaluation.objects import (
    DETECTED_RECALL,
    ObjectRecall,
    ObjectSummary,
    markdown_object_table,
    object_recalls,
    simulator_kinds,
    summarise_objects,
)
from harborsight.perception.classes import CLASS_NAMES, IGNORE, NUM_CLASSES, OBSTACLE, SHIP, WATER

if TYPE_CHECKING:
    from harborsight.perception.segment_images import SegmentOptions

#: Table II's IoU columns: (header, class id), in the paper's order.
TABLE_IOU_COLUMNS = (("Obstacle", OBSTACLE), ("Water", WATER), ("Ship", SHIP))


def confusion_matrix(labels: np.ndarray, predictions: np.ndarray, num_classes: int = NUM_CLASSES,
                     ignore_index: int = IGNORE) -> np.ndarray:
    """int64 ``(C, C)`` matrix ``M[t, p]``; pixels labelled ``ignore_index`` are skipped."""
    if labels.shape != predictions.shape:
        raise ValueError(f"labels {labels.shape} and predictions {predictions.shape} differ in shape")
    valid = labels != ignore_index
    truth = labels[valid].astype(np.int64)
    guess = predictions[valid].astype(np.int64)
    if truth.size and (truth.max() >= num_classes or truth.min() < 0):
        raise ValueError(f"label values outside 0..{num_classes - 1} (and {ignore_index})")
    if guess.size and (guess.max() >= num_classes or guess.min() < 0):
        raise ValueError(f"predicted class outside 0..{num_classes - 1}")
    counts = np.bincount(truth * num_classes + guess, minlength=num_classes * num_classes)
    return counts.reshape(num_classes, num_classes)


@dataclass(frozen=True)
class SegmentationScores:
    """Metrics of a confusion matrix (module docstring); NaN where a class is undefined."""

    confusion: np.ndarray
    class_names: tuple[str, ...] = CLASS_NAMES

    @property
    def pixels(self) -> int:
        return int(self.confusion.sum())

    @property
    def pixel_accuracy(self) -> float:
        return float(np.trace(self.confusion) / self.pixels) if self.pixels else float("nan")

    @property
    def class_accuracy(self) -> np.ndarray:
        truth = self.confusion.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(truth > 0, np.diag(self.confusion) / truth, np.nan)

    @property
    def mean_accuracy(self) -> float:
        acc = self.class_accuracy
        return float(np.nanmean(acc)) if np.isfinite(acc).any() else float("nan")

    @property
    def iou(self) -> np.ndarray:
        tp = np.diag(self.confusion)
        union = self.confusion.sum(axis=1) + self.confusion.sum(axis=0) - tp
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(union > 0, tp / union, np.nan)

    @property
    def miou(self) -> float:
        iou = self.iou
        return float(np.nanmean(iou)) if np.isfinite(iou).any() else float("nan")

    def to_dict(self) -> dict:
        """JSON-ready: fractions in [0, 1], ``None`` for undefined values."""
        def num(x: float) -> float | None:
            return None if not np.isfinite(x) else float(x)

        return {
            "pixels": self.pixels,
            "pixel_accuracy": num(self.pixel_accuracy),
            "mean_accuracy": num(self.mean_accuracy),
            "class_accuracy": {n: num(a) for n, a in zip(self.class_names, self.class_accuracy,
                                                         strict=True)},
            "iou": {n: num(v) for n, v in zip(self.class_names, self.iou, strict=True)},
            "miou": num(self.miou),
            "confusion": self.confusion.tolist(),
        }


def score_frames(segment: Callable[[np.ndarray], np.ndarray], frames: Sequence,
                 on_frame: Callable[[int], None] | None = None) -> SegmentationScores:
    """Accumulate the confusion matrix of ``segment(image) -> labels`` over ``(image, labels)``
    pairs."""
    return score_frames_grouped(segment, frames, None, on_frame)[0]


def score_frames_grouped(
    segment: Callable[[np.ndarray], np.ndarray], frames: Sequence,
    groups: Sequence[Hashable] | None, on_frame: Callable[[int], None] | None = None,
    on_prediction: Callable[[int, np.ndarray, np.ndarray, np.ndarray], None] | None = None,
) -> tuple[SegmentationScores, dict[Hashable, SegmentationScores]]:
    """:func:`score_frames` over all frames, and per group (``groups[i]`` is frame ``i``'s key;
    ``None`` keys and ``groups=None`` add to the total only). ``on_prediction(i, image,
    labels, predicted)`` sees every frame's prediction."""
    confusion = np.zeros((NUM_CLASSES, NUM_CLASSES), np.int64)
    per_group: dict[Hashable, np.ndarray] = {}
    for i, (image, labels) in enumerate(frames):
        predicted = segment(image)
        if predicted.shape != labels.shape:
            raise ValueError(f"frame {i}: prediction {predicted.shape} vs labels {labels.shape}")
        frame_confusion = confusion_matrix(labels, predicted)
        if on_prediction:
            on_prediction(i, image, labels, predicted)
        confusion += frame_confusion
        key = None if groups is None else groups[i]
        if key is not None:
            per_group.setdefault(key, np.zeros_like(confusion))
            per_group[key] += frame_confusion
        if on_frame:
            on_frame(i)
    return SegmentationScores(confusion), {k: SegmentationScores(v) for k, v in per_group.items()}


def height_bins_m(records: Sequence, bin_m: float) -> list[float | None]:
    """Each frame's drone height above water (``uav.alt_m - water_level_m`` of
    ``frames/<stem>.json``) rounded to a multiple of ``bin_m``; ``None`` where a frame has no
    readable metadata (it then counts in the totals only)."""
    from harborsight.frame import load_frame_metadata

    heights: list[float | None] = []
    for record in records:
        path = Path(record.dataset_dir) / "frames" / f"{record.stem}.json"
        try:
            height_m = load_frame_metadata(path).height_above_water_m
        except HarborsightError:
            heights.append(None)
            continue
        heights.append(float(math.floor(height_m / bin_m + 0.5) * bin_m))   # halves go up
    return heights


def frames_per_second(segment: Callable[[np.ndarray], np.ndarray], image: np.ndarray,
                      warmup: int = 3, min_seconds: float = 2.0, min_runs: int = 5) -> float:
    """Calls per second of ``segment(image)`` after ``warmup`` untimed calls, timed over at
    least ``min_seconds`` and ``min_runs`` calls."""
    for _ in range(warmup):
        segment(image)
    runs, start = 0, time.perf_counter()
    while runs < min_runs or time.perf_counter() - start < min_seconds:
        segment(image)
        runs += 1
    return runs / (time.perf_counter() - start)


@dataclass
class LoadedSegmenter:
    """A model file ready to segment: a torch checkpoint (.pt) or an ONNX model (.onnx)."""

    path: Path
    kind: str                                  # "torch" | "onnx"
    network: str
    segment: Callable[[np.ndarray], np.ndarray]
    params: int | None
    input_hw: tuple[int, int] | None           # fixed input size (ONNX), else None
    metadata: dict = field(default_factory=dict)


def _onnx_parameter_count(path: Path) -> int:
    """Elements of the graph's initialisers (weights after export-time folding)."""
    import onnx

    graph = onnx.load(str(path), load_external_data=False).graph
    return int(sum(np.prod(t.dims, dtype=np.int64) for t in graph.initializer))


def load_segmenter(path: str | Path, device: str = "cpu", threads: int | None = None,
                   reference_arithmetic: bool = False) -> LoadedSegmenter:
    """Open ``.onnx`` with ONNX Runtime (no torch needed; ``reference_arithmetic``: see
    :class:`~harborsight.perception.onnx_segmenter.OnnxSegmenter`) or a ``.pt`` checkpoint
    with torch."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, None, "model file not found")
    if path.suffix.lower() == ".onnx":
        from harborsight.perception.default_model import load_onnx_segmenter

        onnx_model = load_onnx_segmenter(path, threads, reference_arithmetic)
        meta = onnx_model.metadata
        params = meta.get("params")
        return LoadedSegmenter(
            path, "onnx", str(meta.get("network", path.stem)), onnx_model.segment,
            int(params) if params is not None else _onnx_parameter_count(path),
            (onnx_model.input_height, onnx_model.input_width), meta)
    if path.suffix.lower() in (".pt", ".pth"):
        try:
            import torch

            from harborsight.perception.model import TorchSegmenter
            from harborsight.perception.networks import inference_parameter_count
            from harborsight.training.checkpoint import load_checkpoint, model_from_checkpoint
        except ImportError as exc:
            raise InputError(path, None, f"torch checkpoints need the train extra: {exc}") from None
        if threads:
            torch.set_num_threads(threads)
        payload = load_checkpoint(path)
        model = model_from_checkpoint(payload, source=path).to(device)
        runner = TorchSegmenter(model, device, amp=False)
        meta = {k: payload.get(k) for k in ("iteration", "val_miou", "best_val_miou", "command")}
        return LoadedSegmenter(path, "torch", payload["network"], runner.segment,
                               inference_parameter_count(model.network), None, meta)
    raise InputError(path, None, "expected a .onnx model or a .pt checkpoint")


@dataclass
class SplitEvaluation:
    """One Table II row: a model on one split."""

    split: str
    frames: int
    scores: SegmentationScores
    #: per drone height above water (m, binned), frames and scores; empty without metadata
    by_height_m: dict[float, tuple[int, SegmentationScores]] = field(default_factory=dict)
    #: per kind of object, its recall (evaluation.objects); empty unless asked for
    objects: list[ObjectSummary] = field(default_factory=list)
    #: ``(path, reason)`` of each frame left out because a file of it could not be read
    skipped: list[tuple[str, str]] = field(default_factory=list)
    #: frames scored in the totals but missing from ``by_height_m``: no readable metadata
    frames_without_height: int = 0


@dataclass
class SegmentationEvaluation:
    model: LoadedSegmenter
    data_dirs: list[Path]
    rows: list[SplitEvaluation]
    fps: float | None
    resolution_wh: tuple[int, int]
    #: how the frames were segmented (SegmentOptions.to_dict, or the predictions folder)
    mode: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "schema": "harborsight.segmentation-evaluation/1",
            "model": str(self.model.path), "kind": self.model.kind, "network": self.model.network,
            "params": self.model.params, "data": [str(d) for d in self.data_dirs],
            "mode": self.mode or None,
            "fps": self.fps, "resolution_wh": list(self.resolution_wh),
            "mean_accuracy_definition": "mean over classes of per-class pixel accuracy (recall)",
            "splits": {r.split: {"frames": r.frames, **r.scores.to_dict(), "by_height_m": [
                {"height_m": h, "frames": n, **sc.to_dict()}
                for h, (n, sc) in sorted(r.by_height_m.items())],
                "frames_without_height": r.frames_without_height,
                "objects": [asdict(o) for o in r.objects],
                "skipped_frames": [{"path": path, "error": error} for path, error in r.skipped],
            } for r in self.rows},
        }

    def markdown(self) -> str:
        """Table II, then per split a table by drone height where frames have metadata."""
        parts = [markdown_table([self])]
        for row in self.rows:
            if row.skipped:
                parts.append(f"\n{row.split} split: {len(row.skipped)} frame(s) left out, "
                             "unreadable:\n\n" + "".join(f"* {error}\n" for _, error in row.skipped))
            if row.by_height_m:
                parts.append(f"\n{self.model.network}, {row.split} split, by drone height above "
                             "water:\n\n" + height_table(row))
            if row.objects:
                parts.append(f"\n{self.model.network}, {row.split} split, recall per object "
                             "(solid recall: share of the object's pixels not taken for water; "
                             f"detected: at least {DETECTED_RECALL:.0%}):\n\n"
                             + markdown_object_table(row.objects))
        return "".join(parts)


def evaluate_segmentation(
    model_path: str | Path, data_dirs: Sequence[str | Path], splits: Sequence[str] = ("test",),
    fps_seconds: float = 2.0, device: str = "cpu", threads: int | None = None,
    on_frame: Callable[[int], None] | None = None, height_bin_m: float = 10.0,
    by_object: bool = False, on_split: Callable[[str, int], None] | None = None,
    options: SegmentOptions | None = None, predictions: str | Path | None = None,
    reference_arithmetic: bool = False,
) -> SegmentationEvaluation:
    """Score a model on each split of the datasets, also per drone height (bins of
    ``height_bin_m``; 0: no breakdown), per object (``by_object``: needs the datasets'
    ``instances/``; :mod:`harborsight.evaluation.objects`), and time it (``fps_seconds <= 0``:
    no timing). The resolution is the network's input: the ONNX model's fixed size, or the
    frames' most common size for a checkpoint. ``on_split(split, n_frames)`` is called when a
    split's frames are read and checked, before they are scored (``on_frame`` per frame).

    ``options``: how an ONNX model meets frames of another size
    (:mod:`harborsight.perception.segment_images`; ``tiles`` needs an ONNX model). With
    ``predictions`` (a folder; ``model_path`` None) no model runs: ``<predictions>/<stem>.png``
    is scored as frame ``<stem>``'s labels, and a frame whose prediction is missing,
    unreadable, of another size or with values outside the classes is left out as skipped."""
    from harborsight.perception.segment_images import SegmentOptions, segment_function
    from harborsight.training.dataset import SegmentationFrames

    options = options or SegmentOptions()
    if predictions is not None:
        if model_path is not None or options.mode == "tiles" or options.flips != 1:
            raise InputError(predictions, "--predictions", "scores written masks: give no "
                             "--model, --mode tiles or --flips with it")
        predictions = Path(predictions)
        if not predictions.is_dir():
            raise InputError(predictions, "--predictions", "folder not found")
        loaded = LoadedSegmenter(predictions, "predictions", "predictions", lambda image: image,
                                 None, None)
        mode = {"mode": "predictions", "predictions": str(predictions)}
    else:
        loaded = load_segmenter(model_path, device, threads, reference_arithmetic)
        if options.mode in ("tiles", "auto") or options.flips != 1:
            if loaded.kind != "onnx" and options.mode in ("tiles", "auto"):
                raise InputError(model_path, "--mode", f"{options.mode} needs an ONNX model (a "
                                 "fixed input size to cut the windows to)")
            if loaded.kind != "onnx":
                raise InputError(model_path, "--flips", "test-time flips need an ONNX model")
            from harborsight.perception.default_model import load_onnx_segmenter

            loaded.segment = segment_function(
                load_onnx_segmenter(loaded.path, threads, reference_arithmetic), options)
        # a checkpoint runs at each frame's own size (TorchSegmenter pads inside)
        mode = options.to_dict() if loaded.kind == "onnx" else {"mode": "frame size"}
        if loaded.kind == "onnx":
            from harborsight.perception.onnx_segmenter import int8_arithmetic

            arithmetic = int8_arithmetic(loaded.path, reference_arithmetic)
            if arithmetic is not None:      # an int8 model: how its convolutions ran
                mode["int8_arithmetic"] = arithmetic
    rows, sizes = [], []
    for split in splits:
        frames = SegmentationFrames(data_dirs, [split])
        skipped = frames.drop_unreadable(instances=by_object)
        segment, scored = loaded.segment, frames
        if predictions is not None:
            skipped += _drop_missing_predictions(frames, predictions)
            scored = _PredictedFrames(frames, predictions)
            segment = scored.prediction
        if on_split is not None:
            on_split(split, len(frames))
        sizes.append(frames.common_size_hw())
        heights = height_bins_m(frames.records, height_bin_m) if height_bin_m > 0 else None
        objects: list[ObjectRecall] = []
        kinds_of: dict[Path, Callable | None] = {}

        def score_objects(i: int, image: np.ndarray, labels: np.ndarray, predicted: np.ndarray,
                          frames=frames, objects=objects, kinds_of=kinds_of) -> None:
            record = frames.records[i]
            if record.dataset_dir not in kinds_of:
                kinds_of[record.dataset_dir] = simulator_kinds(record.dataset_dir)
            kinds = kinds_of[record.dataset_dir]
            objects.extend(object_recalls(record.stem, image, labels, predicted,
                                          frames.instances(i, labels.shape),
                                          kinds(record.stem) if kinds else None))

        total, by_height = score_frames_grouped(segment, scored, heights, on_frame,
                                                score_objects if by_object else None)
        counts = Counter(h for h in heights or [] if h is not None)
        rows.append(SplitEvaluation(split, len(frames), total,
                                    {h: (counts[h], sc) for h, sc in by_height.items()},
                                    summarise_objects(objects), skipped,
                                    sum(h is None for h in heights) if heights else 0))
    frame_hw = max(set(sizes), key=sizes.count)
    fps = None
    if fps_seconds > 0 and predictions is None:
        image = np.random.default_rng(0).integers(0, 256, (*frame_hw, 3), dtype=np.uint8)
        fps = frames_per_second(loaded.segment, image, min_seconds=fps_seconds)
    net_hw = loaded.input_hw or frame_hw
    return SegmentationEvaluation(loaded, [Path(d) for d in data_dirs], rows, fps,
                                  (net_hw[1], net_hw[0]), mode)


def _drop_missing_predictions(frames, folder: Path) -> list[tuple[str, str]]:
    """Leave out of ``frames`` (a SegmentationFrames) each frame without a usable
    ``folder/<stem>.png``: missing, unreadable, of another size than the frame, with values
    outside the classes on labelled pixels (255 where the label is 255 is fine: not scored),
    or a stem that several datasets share (the file would be ambiguous).
    Returns ``(path, reason)`` of each; none usable is an :class:`InputError`."""
    from harborsight.images import read_mask
    from harborsight.training.dataset import _image_size_hw

    stems = Counter(record.stem for record in frames.records)
    kept, dropped = [], []
    for record in frames.records:
        path = folder / f"{record.stem}.png"
        try:
            if stems[record.stem] > 1:
                raise InputError(path, "--predictions", f"frame {record.stem!r} is in several "
                                 "datasets; one prediction file cannot stand for each")
            predicted = read_mask(path)
            frame_hw = _image_size_hw(record.image_path)
            if predicted.shape != frame_hw:
                raise InputError(path, "mask", f"size {predicted.shape[1]}x{predicted.shape[0]} "
                                 f"differs from the frame's {frame_hw[1]}x{frame_hw[0]} "
                                 f"({record.image_path})")
            if predicted.dtype != np.uint8:
                raise InputError(path, "mask", f"expected uint8 class ids 0..{NUM_CLASSES - 1}, "
                                 f"got {predicted.dtype}")
            if predicted.max(initial=0) >= NUM_CLASSES:
                # a value outside the classes is no answer: where the label is ignored too
                # it is not scored (a prediction may copy the labels' 255), elsewhere the
                # frame cannot be scored honestly and is left out, saying where
                labels = read_mask(record.label_path)
                stray = (predicted >= NUM_CLASSES) & (labels != IGNORE)
                if stray.any():
                    raise InputError(path, "mask", f"{int(stray.sum())} labelled pixel(s) "
                                     f"predicted {int(predicted[stray].max())}, not among the class ids "
                                     f"0..{NUM_CLASSES - 1} (255 only where the label is 255)")
        except InputError as exc:
            dropped.append((str(path), str(exc)))
        else:
            kept.append(record)
    if not kept:
        raise InputError(folder, "--predictions", f"none of the {len(frames.records)} frame(s) "
                         f"has a usable prediction; first: {dropped[0][1]}")
    frames.records = kept
    return dropped


class _PredictedFrames(Sequence):
    """``frames[i] -> (image, labels)`` that remembers ``i``: :func:`score_frames_grouped`
    calls ``segment(image)`` right after taking frame ``i``, and :meth:`prediction` returns
    that frame's ``folder/<stem>.png``."""

    def __init__(self, frames, folder: Path) -> None:
        self.frames, self.folder, self.index = frames, folder, -1

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int):
        item = self.frames[index]
        self.index = index
        return item

    def prediction(self, image: np.ndarray) -> np.ndarray:
        """The frame's mask, values outside the classes (only where its label is ignored,
        :func:`_drop_missing_predictions`) made 0: not scored."""
        from harborsight.images import read_mask

        predicted = read_mask(self.folder / f"{self.frames.records[self.index].stem}.png")
        predicted[predicted >= NUM_CLASSES] = 0
        return predicted


def _percent(x: float) -> str:
    return "—" if not np.isfinite(x) else f"{100.0 * x:.1f}"


def _millions(n: int | None) -> str:
    return "—" if n is None else f"{n / 1e6:.1f}M"


def markdown_table(evaluations: Sequence[SegmentationEvaluation]) -> str:
    """Table II: model, split, mean accuracy, IoU (obstacle, water, ship, mean) in percent,
    FPS, network resolution (w, h) and parameter count."""
    lines = [
        "| Model | Dataset | Mean accuracy | IoU Obstacle | IoU Water | IoU Ship | IoU Mean "
        "| Speed (FPS) | Resolution (w,h) | Params |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for ev in evaluations:
        for row in ev.rows:
            iou = row.scores.iou
            cells = [ev.model.network, row.split.capitalize(), _percent(row.scores.mean_accuracy),
                     *(_percent(iou[c]) for _, c in TABLE_IOU_COLUMNS), _percent(row.scores.miou),
                     "—" if ev.fps is None else f"{ev.fps:.2f}",
                     f"{ev.resolution_wh[0]}x{ev.resolution_wh[1]}", _millions(ev.model.params)]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def height_table(row: SplitEvaluation) -> str:
    """Markdown: drone height, frames, mean accuracy and IoU per class and mean, in percent."""
    lines = ["| height m | frames | Mean accuracy | IoU Obstacle | IoU Water | IoU Ship | IoU Mean |",
             "|---:|---:|---:|---:|---:|---:|---:|"]
    for height_m, (n, scores) in sorted(row.by_height_m.items()):
        cells = [f"{height_m:g}", str(n), _percent(scores.mean_accuracy),
                 *(_percent(scores.iou[c]) for _, c in TABLE_IOU_COLUMNS), _percent(scores.miou)]
        lines.append("| " + " | ".join(cells) + " |")
    if row.frames_without_height:
        lines.append(f"\n{row.frames_without_height} frame(s) without readable metadata "
                     "(frames/<stem>.json) count in the totals but not in this table.")
    return "\n".join(lines) + "\n"
