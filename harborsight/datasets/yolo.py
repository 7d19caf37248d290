"""YOLO label files (one ``.txt`` per image) -> frames to import, or boxes.

Segmentation lines are ``class x1 y1 x2 y2 ...`` (at least three points), box lines
``class cx cy w h``; coordinates are fractions of the image's width and height, the class a
0-based index into the class names of a ``data.yaml``/``classes.yaml`` (``names:``) or a
``classes.txt``. A label file ``LABELS/<rel>/<stem>.txt`` belongs to the image
``IMAGES/<rel>/<stem>.<ext>``; IMAGES defaults to the ``images`` folder that stands where
``labels`` does in the path (Ultralytics' layout), else ``images/`` beside the labels
folder, else the labels folder itself. Boxes are not masks: they are read by
:func:`read_yolo_boxes` for ``harborsight dataset label-from-boxes``, never painted.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from harborsight.datasets.annotations import AnnotationSet, FrameAnnotation, Issue, Polygons, Shape
from harborsight.datasets.classmap import class_of, unknown_labels_error
from harborsight.errors import InputError
from harborsight.images import decode_image_file

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")
#: files in a labels folder that are not label files
NOT_LABEL_FILES = ("classes.txt",)


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in pixels of its image (x right, y down; x1/y1 exclusive)."""

    label: str        # the annotation's own class name, e.g. "boat"
    class_id: int     # harborsight class after --map: 0 water, 1 ship, 2 obstacle, 255 ignore
    x0: float
    y0: float
    x1: float
    y1: float


@dataclass(frozen=True)
class ImageBoxes:
    image_path: Path
    width: int
    height: int
    boxes: tuple[Box, ...]


def default_images_dir(labels_dir: Path) -> Path:
    """Where the images of a labels folder are when no ``--images`` is given."""
    labels_dir = Path(labels_dir)
    parts = labels_dir.parts
    if "labels" in parts:
        k = len(parts) - 1 - parts[::-1].index("labels")
        mirror = Path(*parts[:k], "images", *parts[k + 1:])
        if mirror.is_dir():
            return mirror
    if (labels_dir.parent / "images").is_dir():
        return labels_dir.parent / "images"
    return labels_dir


def _label_files(labels_dir: Path) -> list[Path]:
    return sorted(p for p in labels_dir.rglob("*.txt")
                  if p.is_file() and p.name.lower() not in NOT_LABEL_FILES)


def _image_index(images_dir: Path) -> dict[tuple[str, str], list[Path]]:
    index: dict[tuple[str, str], list[Path]] = {}
    if images_dir.is_dir():
        for p in sorted(images_dir.rglob("*")):
            if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file():
                rel = p.relative_to(images_dir)
                index.setdefault((rel.parent.as_posix(), rel.stem), []).append(p)
    return index


@dataclass
class _LabelFile:
    path: Path
    image: Path | None
    lines: list[tuple[int, int, np.ndarray]]   # (line number, class id, coordinates)
    problems: list[Issue]
    empty: bool


def _parse(path: Path, image: Path | None, n_names: int, names_file: str) -> _LabelFile:
    result = _LabelFile(path, image, [], [], False)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        result.problems.append(Issue(str(path), None, f"cannot read: {exc}"))
        return result
    result.empty = not text.strip()
    for number, line in enumerate(text.splitlines(), 1):
        tokens = line.split()
        if not tokens:
            continue
        try:
            values = np.array([float(t) for t in tokens])
        except ValueError:
            result.problems.append(Issue(str(path), f"line {number}", f"expected numbers, got {line[:40]!r}"))
            continue
        if not np.isfinite(values).all() or values[0] != int(values[0]) or values[0] < 0:
            result.problems.append(Issue(str(path), f"line {number}", "expected a class index and "
                                         f"finite coordinates, got {line[:40]!r}"))
            continue
        if int(values[0]) >= n_names:
            result.problems.append(Issue(str(path), f"line {number}", f"class {int(values[0])} has no "
                                         f"name ({names_file} names {n_names}: 0..{n_names - 1})"))
            continue
        result.lines.append((number, int(values[0]), values[1:]))
    return result


def _read_folder(labels_dir: Path, images_dir: Path | None, class_names: list[str],
                 names_file: str, issues: list[Issue]) -> list[_LabelFile]:
    labels_dir = Path(labels_dir)
    if labels_dir.is_file():
        files, labels_dir = [labels_dir], labels_dir.parent
    elif labels_dir.is_dir():
        files = _label_files(labels_dir)
        if not files:
            issues.append(Issue(str(labels_dir), None, "no .txt label files in this folder"))
    else:
        issues.append(Issue(str(labels_dir), None, "not found"))
        return []
    images_dir = Path(images_dir) if images_dir is not None else default_images_dir(labels_dir)
    index = _image_index(images_dir)
    parsed = []
    for path in files:
        rel = path.relative_to(labels_dir)
        candidates = index.get((rel.parent.as_posix(), rel.stem), [])
        item = _parse(path, candidates[0] if len(candidates) == 1 else None, len(class_names), names_file)
        if not candidates:
            item.problems.insert(0, Issue(str(path), "image", f"no image {rel.with_suffix('.*')} "
                                          f"in {images_dir}"))
            item.image = images_dir / rel.with_suffix(".png")
        elif len(candidates) > 1:
            item.problems.insert(0, Issue(str(path), "image", "two or more images of this name: "
                                          + ", ".join(str(c) for c in candidates)))
            item.image = candidates[0]
        parsed.append(item)
    return parsed


def read_yolo_seg(sources: list[Path], images_dir: Path | None, class_names: list[str],
                  names_file: str = "the class names") -> AnnotationSet:
    """Frames of YOLO segmentation label folders (or files). A box line (``class cx cy w h``)
    in a segmentation file makes its frame unusable: boxes are not masks."""
    out = AnnotationSet("yolo-seg")
    for source in sources:
        for item in _read_folder(Path(source), images_dir, class_names, names_file, out.issues):
            out.files.append(str(item.path))
            frame = FrameAnnotation(str(item.path), "", item.image, problems=list(item.problems))
            if item.empty:
                frame.unlabelled_reason = "empty annotation file: no objects (an unlabelled image)"
            for number, cid, coords in item.lines:
                at = f"line {number}"
                if coords.size == 4:
                    frame.problem(at, "a box (class cx cy w h), not a polygon: boxes are not masks "
                                  "(see harborsight dataset label-from-boxes)")
                elif coords.size % 2:
                    frame.problem(at, f"an odd count of coordinates ({coords.size})")
                elif coords.size < 6:
                    frame.warn(at, f"{coords.size // 2} point(s); a polygon needs at least 3; left out")
                else:
                    frame.shapes.append(Shape(class_names[cid], Polygons((coords.reshape(-1, 2),),
                                                                         normalised=True), at))
            out.frames.append(frame)
    return out


def image_size_hw(path: Path) -> tuple[int, int]:
    """(height, width) of an image as harborsight reads it (OpenCV, EXIF orientation applied);
    :class:`InputError` for a missing or undecodable file."""
    image, reason = decode_image_file(path, cv2.IMREAD_COLOR)
    if reason:
        raise InputError(path, None, reason)
    if image is None:
        raise InputError(path, None, "cannot decode image (missing, corrupt or not an image)")
    return image.shape[:2]


def read_yolo_boxes(labels_dir: Path, images_dir: Path, class_names: list[str],
                    mapping: dict[str, int]) -> tuple[list[ImageBoxes], list[tuple[str, str]]]:
    """The boxes of a folder of YOLO box files (``class cx cy w h``, normalised), in pixels of
    their images, clipped to the image; a box wholly outside its image is left out. An empty
    file gives an image without boxes (YOLO's background image).

    Each ``Box.class_id`` is the harborsight class of its class name after ``mapping``
    (:func:`harborsight.datasets.classmap.parse_class_map`; names that are harborsight's own
    need none). Raises :class:`InputError` listing every class name in use that has no class.
    Returns the images with their boxes (sorted by label file) and ``(path, reason)`` of each
    label file skipped: no image, an unreadable image, a malformed line."""
    issues: list[Issue] = []
    parsed = _read_folder(Path(labels_dir), images_dir, class_names, "the class names", issues)
    used = Counter()
    first_file: dict[str, str] = {}
    for item in parsed:
        for _, cid, _ in item.lines:
            used[class_names[cid]] += 1
            first_file.setdefault(class_names[cid], str(item.path))
    unknown = {name: n for name, n in used.items() if class_of(name, mapping) is None}
    if unknown:
        raise unknown_labels_error(str(labels_dir), unknown, first_file)
    results: list[ImageBoxes] = []
    skipped = [(issue.file, str(issue)) for issue in issues]
    for item in parsed:
        problems = list(item.problems) + [
            Issue(str(item.path), f"line {n}", f"expected class cx cy w h (5 numbers), got "
                  f"{coords.size + 1}") for n, _, coords in item.lines if coords.size != 4]
        if not problems:
            try:
                height, width = image_size_hw(item.image)
            except InputError as exc:
                problems.append(Issue(str(item.path), "image", str(exc)))
        if problems:
            skipped.append((str(item.path), "; ".join(str(p) for p in problems)))
            continue
        boxes = []
        for _, cid, (cx, cy, w, h) in item.lines:
            x0, x1 = np.clip([(cx - w / 2) * width, (cx + w / 2) * width], 0, width)
            y0, y1 = np.clip([(cy - h / 2) * height, (cy + h / 2) * height], 0, height)
            if x1 > x0 and y1 > y0:
                label = class_names[cid]
                boxes.append(Box(label, int(class_of(label, mapping)), float(x0), float(y0),
                                 float(x1), float(y1)))
        results.append(ImageBoxes(item.image, width, height, tuple(boxes)))
    return results, skipped
