"""Readers of annotation formats, one entry point: :func:`read_annotations`.

Formats: ``coco`` (:mod:`~harborsight.datasets.coco`), ``labelme``
(:mod:`~harborsight.datasets.labelme`), ``cvat`` (:mod:`~harborsight.datasets.cvat`),
``yolo-seg`` (:mod:`~harborsight.datasets.yolo`). ``yolo-boxes`` is read by
:func:`read_yolo_boxes` only: boxes are not masks. Every reader gives an
:class:`~harborsight.datasets.annotations.AnnotationSet`: frames with their shapes (in their
own class names) and the problems found, before any image is read; the conventions of
coordinates and drawing order are in :mod:`harborsight.datasets.annotations`.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from harborsight.datasets.annotations import AnnotationSet
from harborsight.datasets.classmap import (
    class_of,
    find_class_names_file,
    normalise_name,
    parse_class_map,
    read_class_names,
    unknown_labels_error,
)
from harborsight.datasets.yolo import Box, ImageBoxes, default_images_dir, read_yolo_boxes
from harborsight.errors import InputError

FORMATS = ("coco", "labelme", "cvat", "yolo-seg", "yolo-boxes")
#: other spellings accepted for --format
ALIASES = {"yolo": "yolo-seg", "yolo-segmentation": "yolo-seg", "cvat-images": "cvat",
           "cvat-xml": "cvat", "yolo-box": "yolo-boxes", "yolo-detection": "yolo-boxes"}

__all__ = ["FORMATS", "Box", "ImageBoxes", "check_labels", "normalise_format", "parse_class_map",
           "read_annotations", "read_class_names", "read_yolo_boxes", "yolo_class_names"]


def normalise_format(name: str) -> str:
    """The canonical format name of ``--format``; :class:`InputError` for an unknown one."""
    key = str(name).strip().lower()
    key = ALIASES.get(key, key)
    if key not in FORMATS:
        raise InputError(None, "--format", f"unknown format {name!r}; choose from {', '.join(FORMATS)}")
    return key


def yolo_class_names(sources: list[Path], classes_path: Path | None) -> tuple[list[str], Path]:
    """The class names of YOLO label folders: from ``classes_path``, else the first
    ``data.yaml``/``dataset.yaml``/``classes.yaml``/``classes.txt`` in a labels folder, the
    two folders above it (``ROOT/labels/train``), or the images folder's parent."""
    if classes_path is None:
        folders = []
        for source in sources:
            folder = Path(source) if Path(source).is_dir() else Path(source).parent
            folders += [folder, folder.parent, folder.parent.parent, default_images_dir(folder).parent]
        classes_path = find_class_names_file(*folders)
        if classes_path is None:
            raise InputError(", ".join(str(s) for s in sources), "--classes", "no data.yaml, "
                             "classes.yaml or classes.txt found beside the labels: give --classes")
    return read_class_names(classes_path), Path(classes_path)


def read_annotations(fmt: str, sources: list[Path], images_dir: Path | None = None,
                     classes_path: Path | None = None) -> AnnotationSet:
    """Read the annotation files ``sources`` of format ``fmt`` (see the module doc).

    Problems of single files or frames are collected in the result, not raised; raises
    :class:`InputError` only for what stops the whole import: an unknown format, ``yolo-boxes``
    (boxes are not masks), YOLO class names that cannot be found."""
    from harborsight.datasets.coco import read_coco
    from harborsight.datasets.cvat import read_cvat
    from harborsight.datasets.labelme import read_labelme
    from harborsight.datasets.yolo import read_yolo_seg

    fmt = normalise_format(fmt)
    sources = [Path(s) for s in sources]
    if not sources:
        raise InputError(None, "SOURCE", "no annotation file or folder given")
    if fmt == "yolo-boxes":
        raise InputError(None, "--format", "yolo-boxes: boxes are not masks, so import does not "
                         "paint them; make masks from them with `harborsight dataset "
                         "label-from-boxes` (or read them with harborsight.datasets.read_yolo_boxes)")
    if fmt == "coco":
        return read_coco(sources, images_dir)
    if fmt == "labelme":
        return read_labelme(sources, images_dir)
    if fmt == "cvat":
        return read_cvat(sources, images_dir)
    names, names_path = yolo_class_names(sources, classes_path)
    return read_yolo_seg(sources, images_dir, names, str(names_path))


def check_labels(annotations: AnnotationSet, mapping: dict[str, int]) -> dict[str, int]:
    """``{class name (lower case): number of shapes}`` over every frame, after checking that
    each name has a harborsight class (``mapping``, else its own name). Raises
    :class:`InputError` listing every name without one, with the first file it is in."""
    used: Counter[str] = Counter()
    first_file: dict[str, str] = {}
    spelling: dict[str, str] = {}      # the first spelling met, for the message
    for frame in annotations.frames:
        for shape in frame.shapes:
            key = normalise_name(shape.label)
            used[key] += 1
            first_file.setdefault(key, frame.source)
            spelling.setdefault(key, shape.label.strip())
    unknown = {spelling[name]: n for name, n in used.items() if class_of(name, mapping) is None}
    if unknown:
        where = ", ".join(annotations.files[:3]) + (" ..." if len(annotations.files) > 3 else "")
        raise unknown_labels_error(where, unknown, {spelling[k]: f for k, f in first_file.items()})
    return dict(used)
