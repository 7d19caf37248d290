"""Reader of the simulator dataset layout (``docs/design.md``) for training and evaluation.

A dataset folder holds ``dataset.json`` whose ``"split"`` map names the split of every frame
stem (``train``, ``val``, ``test``, ...), ``images/<stem>.png`` (BGR as OpenCV reads it) and
``labels/<stem>.png`` (uint8 class ids: 0 water, 1 ship, 2 obstacle, 255 ignore). Several
folders can be read as one dataset. Pure numpy + OpenCV: no torch, so evaluating an ONNX
model does not need the ``train`` extra.
"""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError
from harborsight.images import read_image, read_image_and_no_data, read_mask
from harborsight.perception.classes import IGNORE, NUM_CLASSES
from harborsight.text_formats import parse_json_text

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
VALID_LABELS = frozenset([*range(NUM_CLASSES), IGNORE])


@dataclass(frozen=True)
class FrameRecord:
    """One labelled frame: where its image and label live and which split it is in."""

    dataset_dir: Path
    stem: str
    split: str
    image_path: Path
    label_path: Path


def read_split_map(dataset_dir: Path) -> dict[str, str]:
    """The ``stem -> split`` map of ``dataset.json``, checked against ``images/``.

    Every image must have a split entry and every entry an image; otherwise an
    :class:`InputError` names the offending file.
    """
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise InputError(dataset_dir, None, "dataset folder not found")
    meta_path = dataset_dir / "dataset.json"
    if not meta_path.is_file():
        raise InputError(meta_path, None, "dataset.json not found (is this a dataset folder?)")
    try:
        meta = parse_json_text(meta_path.read_text(), meta_path)
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(meta_path, None, f"cannot read: {exc}") from None
    split = meta.get("split") if isinstance(meta, dict) else None
    if not isinstance(split, dict) or not split:
        raise InputError(meta_path, "split", "missing or empty: expected a map of frame stem -> split")
    bad = [stem for stem, name in split.items() if not isinstance(name, str) or not name]
    if bad:
        raise InputError(meta_path, f"split.{bad[0]}", "expected a split name (train, val, test)")
    images_dir = dataset_dir / "images"
    if not images_dir.is_dir():
        raise InputError(images_dir, None, "images folder not found")
    frames_dir = dataset_dir / "frames"
    for path in sorted(images_dir.iterdir()):
        if path.suffix.lower() in IMAGE_SUFFIXES and path.stem not in split:
            if frames_dir.is_dir() and not (frames_dir / f"{path.stem}.json").is_file():
                continue  # the simulator writes the frame JSON last: a frame still being written
            raise InputError(path, None, f"no split entry for {path.stem!r} in {meta_path}")
    return {str(stem): name for stem, name in split.items()}


def _image_path(dataset_dir: Path, stem: str) -> Path:
    """The frame's image; ``images/<stem>.png`` when none exists (reading it then fails
    with the frame's name, so one missing image costs one frame, not the dataset)."""
    for suffix in IMAGE_SUFFIXES:
        candidate = dataset_dir / "images" / f"{stem}{suffix}"
        if candidate.is_file():
            return candidate
    return dataset_dir / "images" / f"{stem}.png"


def list_frames(data_dirs: Iterable[str | Path], splits: Sequence[str] | None = None
                ) -> list[FrameRecord]:
    """Frames of the given splits (``None``: every frame) over several dataset folders,
    sorted by folder then stem. Raises :class:`InputError` if nothing is selected."""
    data_dirs = [Path(d) for d in data_dirs]
    if not data_dirs:
        raise InputError(None, "data", "no dataset folder given")
    records = []
    found: Counter[str] = Counter()
    for dataset_dir in data_dirs:
        split_map = read_split_map(dataset_dir)
        found.update(split_map.values())
        for stem in sorted(split_map):
            if splits is not None and split_map[stem] not in splits:
                continue
            records.append(FrameRecord(dataset_dir, stem, split_map[stem],
                                       _image_path(dataset_dir, stem),
                                       dataset_dir / "labels" / f"{stem}.png"))
    if not records:
        have = ", ".join(f"{name} ({n})" for name, n in sorted(found.items())) or "none"
        where = ", ".join(str(d) for d in data_dirs)
        raise InputError(where, "split", f"no frames in split(s) {list(splits or [])}; "
                         f"the dataset has: {have}")
    return records


def read_labelled_frame(record: FrameRecord) -> tuple[np.ndarray, np.ndarray]:
    """uint8 BGR image (H, W, 3) and uint8 labels (H, W) of one frame, validated. Pixels the
    image holds no picture for (alpha 0, a GeoTIFF's no-data value) are black and labelled
    255, as ``segment`` and measuring see them: an annotation's background there is not
    seen water, and a model must not learn that black is."""
    if not record.image_path.is_file():
        raise InputError(record.image_path, None, f"image file not found (frame "
                         f"{record.stem!r} is listed in dataset.json)")
    image, no_data = read_image_and_no_data(record.image_path)
    labels = read_mask(record.label_path)
    if labels.dtype != np.uint8:
        raise InputError(record.label_path, "mask", f"expected uint8 class ids, got {labels.dtype}")
    if labels.shape != image.shape[:2]:
        raise InputError(record.label_path, "mask",
                         f"size {labels.shape[1]}x{labels.shape[0]} differs from the image's "
                         f"{image.shape[1]}x{image.shape[0]} ({record.image_path.name})")
    unknown = sorted(set(np.unique(labels).tolist()) - VALID_LABELS)
    if unknown:
        raise InputError(record.label_path, "mask", f"unknown class values {unknown[:8]}")
    if no_data is not None:
        labels = labels.copy()
        labels[no_data] = IGNORE
    return image, labels


def read_instances(record: FrameRecord, labels_hw: tuple[int, int]) -> np.ndarray:
    """The frame's ``instances/<stem>.png`` (uint16 object ids, 0 water), checked for size."""
    path = record.dataset_dir / "instances" / f"{record.stem}.png"
    if not path.is_file():
        raise InputError(path, None, "instance mask not found (small-object weighting needs the "
                         "simulator's instances/ folder)")
    instances = read_mask(path)
    if instances.shape != labels_hw:
        raise InputError(path, "mask", f"size {instances.shape[1]}x{instances.shape[0]} differs "
                         f"from the labels' {labels_hw[1]}x{labels_hw[0]}")
    return instances


def small_object_weights(instances: np.ndarray, labels: np.ndarray, area_ref_px: float,
                         max_weight: float) -> np.ndarray:
    """Per-pixel loss weights that lift small objects: on the pixels of object ``k``, whose
    visible area in the frame is ``A_k`` pixels,

        w = clip(sqrt(A_ref / A_k), 1, w_max)

    and 1 on water (id 0) and on ignored pixels. A fender of 16 px gets ``sqrt(1000/16) ≈ 7.9``
    with ``A_ref = 1000``; anything of ``A_ref`` pixels or more keeps 1. The square root
    makes a small object's summed weight grow as ``sqrt(A_k)``, so it still counts for less
    than a large one."""
    ids, inverse, counts = np.unique(instances, return_inverse=True, return_counts=True)
    per_id = np.clip(np.sqrt(area_ref_px / counts), 1.0, max_weight)
    per_id[ids == 0] = 1.0
    weights = per_id[inverse.reshape(instances.shape)].astype(np.float32)
    weights[labels == IGNORE] = 1.0
    return weights


class SegmentationFrames(Sequence):
    """Labelled frames of some splits of one or more datasets; ``frames[i] -> (image, labels)``.

    With ``fit_large_hw = (H, W)``, a frame larger than H or W is stretched to exactly H x W
    (image with area filter, labels nearest-neighbour) and smaller ones keep their size: the
    view ``harborsight segment --mode auto`` gives a model with input H x W, so that a model
    trains and validates at the scale it will see (a 1024x768 photo is seen at 640x360, a
    256x256 marina tile at its own scale)."""

    def __init__(self, data_dirs: Iterable[str | Path], splits: Sequence[str] | None = None,
                 fit_large_hw: tuple[int, int] | None = None) -> None:
        self.data_dirs = [Path(d) for d in data_dirs]
        self.splits = None if splits is None else tuple(splits)
        self.records = list_frames(self.data_dirs, self.splits)
        self.fit_large_hw = fit_large_hw

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index):  # Sequence protocol; slices are not needed
        image, labels = read_labelled_frame(self.records[index])
        if self.fit_large_hw is not None:
            height, width = self.fit_large_hw
            if image.shape[0] > height or image.shape[1] > width:
                image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
                labels = cv2.resize(labels, (width, height), interpolation=cv2.INTER_NEAREST_EXACT)
        return image, labels

    def drop_unreadable(self, instances: bool = False) -> list[tuple[str, str]]:
        """Read every frame once (with ``instances``, its instance mask too) and leave out
        those that fail, so that one bad file costs one frame and not a run hours later.
        Returns ``(path, reason)`` of each frame left out."""
        kept, dropped = [], []
        for record in self.records:
            try:
                _, labels = read_labelled_frame(record)
                if instances:
                    read_instances(record, labels.shape)
            except InputError as exc:
                dropped.append((str(exc.source or record.label_path), str(exc)))
            else:
                kept.append(record)
        if not kept:
            raise InputError(", ".join(str(d) for d in self.data_dirs), "split",
                             f"none of the {len(self.records)} frame(s) of split(s) "
                             f"{list(self.splits or [])} is readable; first: {dropped[0][1]}")
        self.records = kept
        return dropped

    def fingerprint(self) -> str:
        """SHA-1 of the frames (dataset number and stem, in order): what a resumed run must
        find again, since the sampling order depends on the frame count and order."""
        number = {d: k for k, d in enumerate(self.data_dirs)}
        names = "\n".join(f"{number[r.dataset_dir]}/{r.stem}" for r in self.records)
        return hashlib.sha1(names.encode()).hexdigest()

    def instances(self, index: int, labels_hw: tuple[int, int]) -> np.ndarray:
        """uint16 object ids of frame ``index`` (:func:`read_instances`), in the same view as
        ``frames[index]`` (stretched like it under ``fit_large_hw``)."""
        record = self.records[index]
        if self.fit_large_hw is None:
            return read_instances(record, labels_hw)
        instances = read_instances(record, _image_size_hw(record.image_path))
        if instances.shape != labels_hw:
            instances = cv2.resize(instances, (labels_hw[1], labels_hw[0]),
                                   interpolation=cv2.INTER_NEAREST_EXACT)
        return instances

    def common_size_hw(self) -> tuple[int, int]:
        """The most frequent (height, width) among the images (reads headers only for PNG)."""
        sizes = Counter(_image_size_hw(r.image_path) for r in self.records)
        return sizes.most_common(1)[0][0]


def _image_size_hw(path: Path) -> tuple[int, int]:
    with path.open("rb") as handle:
        head = handle.read(24)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return int.from_bytes(head[20:24], "big"), int.from_bytes(head[16:20], "big")
    return read_image(path).shape[:2]
