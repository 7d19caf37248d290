"""Write imported annotations as a harborsight dataset folder.

The folder (``docs/design.md``'s layout, without the simulator's ``frames/``,
``instances/`` and ``vessels/``)::

    DIR/dataset.json        schema harborsight.dataset/1: split of each frame, class map, source
    DIR/images/<stem>.<ext> the image: PNG and JPEG copied byte for byte (suffix in lower
                            case), anything else (TIFF, BMP, WebP) converted to PNG
    DIR/labels/<stem>.png   uint8 class mask: 0 water, 1 ship, 2 obstacle, 255 ignore

``<stem>`` is the image file's name without its suffix. ``--max-side`` shrinks a larger
image (``INTER_AREA``; re-encoded: JPEG at quality 95, else PNG) and its mask
(``INTER_NEAREST_EXACT``). ``dataset.json`` is written last, so a folder with one is
complete; it keeps the keys :mod:`harborsight.training.dataset` reads (``split``,
``classes``) and says ``"frames_without_pose": true``: there is no ``frames/<stem>.json``,
so nothing that needs a camera pose (clearance, ``evaluate distance``) applies. How the
masks are drawn: :mod:`harborsight.datasets.annotations`.

The import is planned first (:func:`plan_import`: annotations read, class names checked,
stems and splits settled, the output folder checked), and nothing is written when that
fails; then :func:`run_import` writes frame by frame. A frame that fails (unreadable image,
size that differs from the annotation's, ...) is skipped and listed, the others go on.
"""

from __future__ import annotations

import json
import re
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from harborsight import __version__
from harborsight.datasets.annotations import (
    AnnotationSet,
    CocoRle,
    FrameAnnotation,
    Issue,
    Polygons,
    paint_labels,
)
from harborsight.datasets.classmap import TARGET_NAMES, class_of, splits_of
from harborsight.datasets.importers import check_labels, normalise_format, read_annotations
from harborsight.errors import InputError, brief
from harborsight.files import strict_json, write_bytes_atomic, write_text_atomic
from harborsight.images import decode_as_displayed, exif_orientation, incomplete_reason
from harborsight.perception.classes import IGNORE, WATER

SCHEMA = "harborsight.dataset/1"
CLASSES = {"0": "water", "1": "ship", "2": "obstacle"}
#: image suffixes copied as they are (training reads these)
KEPT_SUFFIXES = (".png", ".jpg", ".jpeg")
SPLIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


@dataclass
class ImportOptions:
    """What ``harborsight dataset import`` was asked for (see its ``--help``)."""

    format: str
    sources: list[Path]
    out_dir: Path
    images_dir: Path | None = None
    classes_path: Path | None = None
    class_map: dict[str, int] = field(default_factory=dict)
    background: int = WATER             # or IGNORE: pixels no shape covers
    split: str = "train"                # every frame's split, unless split_file
    split_file: Path | None = None      # CSV stem,split
    max_side: int | None = None
    append: bool = False
    keep_unlabelled: bool = False       # import frames without any shape (all background)


@dataclass
class ImportPlan:
    options: ImportOptions
    annotations: AnnotationSet
    frames: list[FrameAnnotation]       # to write, in order
    splits: dict[str, str]              # stem -> split of those frames
    skipped: list[Issue]                # left out already: one entry per file or frame
    warnings: list[Issue]
    label_counts: dict[str, int]        # class name (lower case) -> shapes
    existing: dict | None = None        # dataset.json of the dataset appended to


@dataclass
class ImportResult:
    out_dir: Path
    splits: dict[str, str]              # stem -> split of the frames written
    skipped: list[Issue]
    warnings: list[Issue]
    pixels: dict[int, int]              # class value -> pixel count over the written masks
    written_json: bool = False

    def frames_per_split(self) -> dict[str, int]:
        return dict(sorted(Counter(self.splits.values()).items()))

    def pixel_fractions(self) -> dict[str, float]:
        """Share of the written pixels per class name (water, ship, obstacle, ignore)."""
        total = sum(self.pixels.values()) or 1
        return {TARGET_NAMES[v]: self.pixels.get(v, 0) / total for v in sorted(TARGET_NAMES)}


def _frame_issue(frame: FrameAnnotation) -> Issue:
    """One line for a frame with problems: its first, with the others appended."""
    first, *rest = frame.problems
    if not rest:
        return first
    also = "; ".join(f"{p.field}: {p.reason}" if p.field else p.reason for p in rest)
    return Issue(first.file, first.field, f"{first.reason} (also {also})")


def _check_out_dir(out_dir: Path, append: bool) -> dict | None:
    """The dataset.json to extend (``append``), or None for a new dataset; raises
    :class:`InputError` for a folder that may not be written."""
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(out_dir, None, "exists and is not a folder")
    meta_path = out_dir / "dataset.json"
    if append and meta_path.is_file():
        try:
            doc = json.loads(meta_path.read_text())
        except (OSError, ValueError) as exc:
            raise InputError(meta_path, None, f"cannot read: {exc}") from None
        if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
            raise InputError(meta_path, "schema", f"--append adds to a dataset made by harborsight "
                             f"dataset import ({SCHEMA}), not to this one; import into a new folder "
                             "and give both to --data")
        if not isinstance(doc.get("split"), dict):
            raise InputError(meta_path, "split", "missing: expected a map of frame stem -> split")
        return doc
    if out_dir.is_dir() and any(out_dir.iterdir()):
        raise InputError(out_dir, None, "not empty" + (" and has no dataset.json" if append else "")
                         + ": give a new or empty folder"
                         + ("" if append else ", or --append to add to a dataset made by "
                            "harborsight dataset import"))
    return None


def _existing_stems(out_dir: Path, existing: dict | None) -> set[str]:
    stems = set(existing["split"]) if existing else set()
    for sub in ("images", "labels"):
        if (out_dir / sub).is_dir():
            stems |= {p.stem for p in (out_dir / sub).iterdir()}
    return stems


def plan_import(options: ImportOptions) -> ImportPlan:
    """Read and check everything before anything is written. Raises :class:`InputError` for
    a bad option, an output folder that may not be written, a class name without a
    harborsight class, two frames with one stem, or a split file that misses a frame."""
    options.format = normalise_format(options.format)
    if options.max_side is not None and options.max_side < 1:
        raise InputError(None, "--max-side", f"expected a positive number of pixels, got {options.max_side}")
    if options.background not in (WATER, IGNORE):
        raise InputError(None, "--background", "expected water (0) or ignore (255)")
    if options.split_file is None and not SPLIT_NAME.fullmatch(options.split or ""):
        raise InputError(None, "--split", f"expected a split name such as train, val or test, got "
                         f"{options.split!r}")
    out_dir = Path(options.out_dir)
    existing = _check_out_dir(out_dir, options.append)
    annotations = read_annotations(options.format, options.sources, options.images_dir,
                                   options.classes_path)
    label_counts = check_labels(annotations, options.class_map)
    skipped = list(annotations.issues)
    warnings = list(annotations.warnings)
    frames = []
    for frame in annotations.frames:
        if frame.problems:
            skipped.append(_frame_issue(frame))
        elif not frame.shapes and not options.keep_unlabelled:
            skipped.append(Issue(frame.source, frame.where or None, f"{frame.unlabelled_reason}; "
                                 "left out (--keep-unlabelled imports it as all background)"))
        else:
            frames.append(frame)
    by_stem: dict[str, FrameAnnotation] = {}
    for frame in frames:
        other = by_stem.setdefault(frame.stem, frame)
        if other is not frame:
            same = other.image_path == frame.image_path
            raise InputError(frame.source, frame.where or None, (
                f"image {frame.image_path} is annotated twice (also in {other.source}"
                f"{' ' + other.where if other.where else ''})" if same else
                f"images {other.image_path} and {frame.image_path} have one stem "
                f"{frame.stem!r}: rename one (the dataset names frames by stem)"))
    taken = sorted(set(by_stem) & _existing_stems(out_dir, existing))
    if taken:
        raise InputError(out_dir, "split", f"{len(taken)} frame(s) already in the dataset: "
                         + ", ".join(taken[:10]) + (" ..." if len(taken) > 10 else ""))
    if options.split_file is not None:
        splits = splits_of(list(by_stem), None, options.split_file, what="imported frame")
        bad = sorted({name for name in splits.values() if not SPLIT_NAME.fullmatch(name)})
        if bad:
            raise InputError(options.split_file, "split", f"not a split name: {bad[0]!r}")
    else:
        splits = dict.fromkeys(by_stem, options.split)
    return ImportPlan(options, annotations, frames, splits, skipped, warnings, label_counts, existing)


def _read_image(frame: FrameAnnotation) -> tuple[bytes, str]:
    """The image's bytes and the suffix to keep them under (lower case)."""
    if frame.image_path is not None and frame.image_path.is_file():
        return frame.image_path.read_bytes(), frame.image_path.suffix.lower()
    data = frame.image_data or b""
    suffix = ".png" if data[:8] == b"\x89PNG\r\n\x1a\n" else ".jpg" if data[:2] == b"\xff\xd8" else ".img"
    return data, suffix


def _encode(image: np.ndarray, suffix: str) -> tuple[bytes, str]:
    if suffix in (".jpg", ".jpeg"):
        ok, buf = cv2.imencode(suffix, image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    else:
        suffix = ".png"
        ok, buf = cv2.imencode(suffix, image)
    if not ok:
        raise RuntimeError(f"{suffix} encoding failed")
    return buf.tobytes(), suffix


def import_frame(frame: FrameAnnotation, plan: ImportPlan, out_dir: Path
                 ) -> tuple[Issue | None, list[Issue], np.ndarray | None]:
    """Write one frame's image and mask. Returns ``(problem, warnings, pixel counts per
    class value)``; with a problem nothing of the frame is written."""
    options = plan.options
    image_field = frame.where + ".image" if frame.where else "image"
    try:
        data, suffix = _read_image(frame)
    except OSError as exc:
        return Issue(frame.source, image_field, f"cannot read {frame.image_path}: "
                     f"{exc.strerror or exc}"), [], None
    incomplete = incomplete_reason(data) if data else None
    if incomplete:
        return Issue(frame.source, image_field, f"{incomplete} ({frame.image_path})"), [], None
    try:
        image = decode_as_displayed(data, cv2.IMREAD_COLOR)
    except (cv2.error, MemoryError) as exc:
        return Issue(frame.source, image_field, f"cannot decode image {frame.image_path}: "
                     f"{brief(str(exc).splitlines()[-1] if str(exc) else exc, 120)} (more pixels "
                     "than OpenCV decodes?)"), [], None
    if not data:
        return Issue(frame.source, image_field, f"empty file (0 bytes): {frame.image_path}"), [], None
    if image is None:
        return Issue(frame.source, image_field, f"cannot decode image {frame.image_path} (corrupt "
                     "or not an image)"), [], None
    height, width = image.shape[:2]
    if frame.size_hw is not None and frame.size_hw != (height, width):
        orientation = exif_orientation(data)
        turned = (f"; it has EXIF Orientation {orientation} and is {width}x{height} as shown: "
                  f"the annotation's {frame.size_hw[1]}x{frame.size_hw[0]} is the stored size, "
                  "so the tool that drew it did not turn the picture"
                  if orientation in range(5, 9) and frame.size_hw == (width, height) else "")
        return Issue(frame.source, frame.size_field, f"{frame.size_hw[1]}x{frame.size_hw[0]} but "
                     f"the image {frame.image_path.name} is {width}x{height} (a mask of another "
                     f"size){turned}"), [], None
    for shape in frame.shapes:
        if isinstance(shape.geometry, CocoRle) and shape.geometry.size_hw != (height, width):
            h, w = shape.geometry.size_hw
            return Issue(frame.source, shape.field, f"RLE of {w}x{h} but the image "
                         f"{frame.image_path.name} is {width}x{height} (a mask of another size)"), [], None
    warnings = []
    for s in frame.shapes:
        if not s.geometry.outside(height, width):
            continue
        if isinstance(s.geometry, Polygons) and s.geometry.normalised and s.geometry.reach() > 1.05:
            return Issue(frame.source, s.field, f"{s.label!r}: coordinates are fractions of the "
                         f"image's size, and this shape goes up to {s.geometry.reach():.4g} "
                         "(pixels?)"), [], None
        if s.geometry.wholly_outside(height, width):
            return Issue(frame.source, s.field, f"{s.label!r} lies wholly outside the "
                         f"{width}x{height} image (coordinates of another image, or in other "
                         "units?)"), [], None
        warnings.append(Issue(frame.source, s.field, f"{s.label!r} reaches outside the "
                              f"{width}x{height} image; cut off at the image edge"))
    class_ids = [class_of(s.label, options.class_map) for s in frame.shapes]
    labels, unseen = paint_labels(frame.shapes, class_ids, height, width, options.background)
    for k in unseen:
        shape = frame.shapes[k]
        warnings.append(Issue(frame.source, shape.field, f"{shape.label!r} has no pixel left: "
                              "painted over whole by shapes drawn after it (later in the file, or "
                              "of a higher z_order), or smaller than a pixel"))
    resized = options.max_side is not None and max(height, width) > options.max_side
    if resized:
        scale = options.max_side / max(height, width)
        size = (max(1, round(width * scale)), max(1, round(height * scale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        labels = cv2.resize(labels, size, interpolation=cv2.INTER_NEAREST_EXACT)
    if resized or suffix not in KEPT_SUFFIXES:
        data, suffix = _encode(image, suffix)
    ok, label_png = cv2.imencode(".png", labels)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    for sub in ("images", "labels"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    try:
        write_bytes_atomic(out_dir / "labels" / f"{frame.stem}.png", label_png.tobytes())
        write_bytes_atomic(out_dir / "images" / f"{frame.stem}{suffix}", data)
    except OSError as exc:
        (out_dir / "labels" / f"{frame.stem}.png").unlink(missing_ok=True)
        return Issue(str(out_dir), None, f"cannot write frame {frame.stem}: {exc.strerror or exc}"), [], None
    return None, warnings, np.bincount(labels.ravel(), minlength=256)


def _dataset_doc(plan: ImportPlan, result: ImportResult) -> dict:
    options = plan.options
    old = plan.existing or {}
    class_map = {name: TARGET_NAMES[class_of(name, options.class_map)]
                 for name in sorted(plan.label_counts)}
    source = {"format": options.format, "files": [str(Path(f).resolve()) for f in plan.annotations.files],
              "images": str(Path(options.images_dir).resolve()) if options.images_dir else None}
    this_import = {
        "time": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"), "source": source,
        "class_map": class_map, "background": TARGET_NAMES[options.background],
        "max_side": options.max_side, "frames": result.frames_per_split(),
        "skipped": len(result.skipped), "warnings": len(result.warnings),
        "shapes_per_class_name": dict(sorted(plan.label_counts.items())),
    }
    return {
        **old,
        "schema": SCHEMA,
        "generator": f"harborsight dataset import {__version__}",
        "source": source,
        "classes": CLASSES,
        "ignore_index": IGNORE,
        "background": TARGET_NAMES[options.background],
        "class_map": class_map,
        "split": {**old.get("split", {}), **result.splits},
        "frames_without_pose": True,
        "skipped": old.get("skipped", []) + [i.to_dict() for i in result.skipped],
        "warnings": old.get("warnings", []) + [i.to_dict() for i in result.warnings],
        "imports": [*old.get("imports", []), this_import],
    }


def run_import(plan: ImportPlan, on_frame: Callable[[str, Issue | None], None] | None = None
               ) -> ImportResult:
    """Write the planned frames, then ``dataset.json`` (also when interrupted, for the frames
    written so far). Nothing is written when no frame could be imported."""
    out_dir = Path(plan.options.out_dir)
    result = ImportResult(out_dir, {}, list(plan.skipped), list(plan.warnings), {})
    if plan.existing is not None:
        old = plan.existing.get("class_map") or {}
        for name in sorted(plan.label_counts):
            new = TARGET_NAMES[class_of(name, plan.options.class_map)]
            if name in old and old[name] != new:
                result.warnings.append(Issue(str(out_dir / "dataset.json"), f"class_map.{name}",
                                             f"was {old[name]}, this import makes it {new}"))
    pixels = np.zeros(256, np.int64)
    try:
        for frame in plan.frames:
            problem, warnings, counts = import_frame(frame, plan, out_dir)
            if problem is None:
                result.splits[frame.stem] = plan.splits[frame.stem]
                result.warnings += frame.warnings + warnings
                pixels += counts
            else:
                result.skipped.append(problem)
            if on_frame is not None:
                on_frame(frame.stem, problem)
    finally:
        result.pixels = {int(v): int(pixels[v]) for v in np.flatnonzero(pixels)}
        if result.splits:
            write_text_atomic(out_dir / "dataset.json",
                              strict_json(_dataset_doc(plan, result), indent=1) + "\n")
            result.written_json = True
    return result


def import_dataset(options: ImportOptions, on_frame: Callable[[str, Issue | None], None] | None = None
                   ) -> ImportResult:
    """:func:`plan_import` then :func:`run_import`."""
    return run_import(plan_import(options), on_frame)
