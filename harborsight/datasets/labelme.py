"""LabelMe JSON (one file per image) -> frames to import.

``shapes[]`` of ``shape_type`` ``polygon`` (also when the type is missing),
``rectangle`` (two opposite corners), ``oriented_rectangle`` (four corners), ``circle``
(the centre, then a point on the circle) and ``mask`` (``points[0]`` the patch's top-left
pixel, ``mask`` a base64 PNG patch, as LabelMe 5 writes it) become regions; ``line``,
``linestrip``, ``point`` and ``points`` have no area and are left out with a warning.
``imagePath`` is relative to the JSON (then looked up in ``--images``); where no file is
there, its bare name is looked up beside the JSON and in ``--images`` (a path of the
machine it was drawn on, ``C:/Users/...``); where no such file exists, an embedded
``imageData`` is used. A file given twice (a folder and one inside it) is read once. ``imageHeight`` and
``imageWidth`` are checked against the image. Coordinates and drawing order:
:mod:`harborsight.datasets.annotations`.
"""

from __future__ import annotations

import base64
import binascii
from pathlib import Path

import cv2
import numpy as np

from harborsight.datasets.annotations import (
    AnnotationSet,
    Bitmap,
    Ellipse,
    FrameAnnotation,
    Issue,
    Polygons,
    Shape,
    find_image,
    load_json_file,
    rectangle,
    ring_from_flat,
)

NOT_AREAS = ("line", "linestrip", "point", "points")


def json_files(sources: list[Path], issues: list[Issue], suffix: str = ".json") -> list[Path]:
    """The files of ``sources``: files as given, folders searched recursively for
    ``*<suffix>`` (sorted); a folder without any is an issue."""
    files: list[Path] = []
    for source in sources:
        source = Path(source)
        if source.is_dir():
            found = sorted(p for p in source.rglob(f"*{suffix}") if p.is_file())
            if not found:
                issues.append(Issue(str(source), None, f"no {suffix} files in this folder"))
            files += found
        elif source.is_file():
            files.append(source)
        else:
            issues.append(Issue(str(source), None, "not found"))
    seen: set[Path] = set()
    unique = []
    for file in files:         # a folder and one inside it, both given: each file once
        if file.resolve() not in seen:
            seen.add(file.resolve())
            unique.append(file)
    return unique


def _decode_b64(text: object) -> bytes:
    if not isinstance(text, str) or not text:
        raise ValueError("expected base64 text")
    try:
        return base64.b64decode(text, validate=False)
    except (binascii.Error, ValueError) as exc:
        raise ValueError(f"not base64: {exc}") from None


def _points(shape: dict) -> np.ndarray:
    try:
        pts = np.asarray(shape.get("points"), dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError("expected a list of [x, y] points") from None
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
        raise ValueError("expected a list of [x, y] points")
    return pts


def _geometry(shape: dict, kind: str):
    """The geometry of one LabelMe shape; ValueError saying what is wrong."""
    pts = _points(shape)
    if kind == "polygon":
        return Polygons((ring_from_flat(pts, "polygon"),))
    if kind == "oriented_rectangle":
        if len(pts) != 4:
            raise ValueError(f"an oriented rectangle has 4 points, not {len(pts)}")
        return Polygons((pts,))
    if kind == "rectangle":
        if len(pts) != 2:
            raise ValueError(f"a rectangle has 2 points (opposite corners), not {len(pts)}")
        return rectangle(pts[0, 0], pts[0, 1], pts[1, 0], pts[1, 1])
    if kind == "circle":
        if len(pts) != 2:
            raise ValueError(f"a circle has 2 points (centre, a point on it), not {len(pts)}")
        radius = float(np.hypot(*(pts[1] - pts[0])))
        return Ellipse(pts[0, 0], pts[0, 1], radius, radius)
    if kind == "mask":
        if len(pts) < 1:
            raise ValueError("a mask needs its top-left corner in points")
        patch = cv2.imdecode(np.frombuffer(_decode_b64(shape.get("mask")), np.uint8),
                             cv2.IMREAD_UNCHANGED)
        if patch is None:
            raise ValueError("mask: not a PNG")
        if patch.ndim == 3:   # a grey patch saved with colour (or grey + alpha) channels
            patch = patch[..., :3].any(axis=2) if patch.shape[2] >= 3 else patch[..., 0]
        left, top = (int(v) for v in np.round(pts[0]))
        return Bitmap(np.asarray(patch) != 0, left, top)
    raise ValueError(f"unknown shape_type {kind!r}")


def read_labelme(sources: list[Path], images_dir: Path | None = None) -> AnnotationSet:
    """Frames of LabelMe files (``sources``: JSON files, or folders searched for them)."""
    out = AnnotationSet("labelme")
    for path in json_files(sources, out.issues):
        out.files.append(str(path))
        frame = _read_file(path, images_dir, out)
        if frame is not None:
            out.frames.append(frame)
    return out


def _read_file(path: Path, images_dir: Path | None, out: AnnotationSet) -> FrameAnnotation | None:
    doc = load_json_file(path, out.issues)
    if doc is None:
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("shapes"), list):
        out.issues.append(Issue(str(path), "shapes", "not a LabelMe file (no shapes list)"))
        return None
    source = str(path)
    name = doc.get("imagePath")
    name = name.replace("\\", "/") if isinstance(name, str) and name else None
    bases = [path.parent] + ([Path(images_dir)] if images_dir is not None else [])
    found = find_image(name, bases) if name else None
    if found is None and name:
        # a path of the machine it was drawn on (C:/Users/...): the file by its name, beside
        # the JSON or in --images
        found = find_image(Path(name).name, bases)
    nominal = found or (path.parent / name if name else path.with_suffix(".png"))
    frame = FrameAnnotation(source, "", nominal, size_field="imageWidth/imageHeight")
    if found is None:
        if doc.get("imageData"):
            try:
                frame.image_data = _decode_b64(doc["imageData"])
            except ValueError as exc:
                frame.problem("imageData", str(exc))
        else:
            frame.problem("imagePath", f"image file not found: {name} (relative to {path.parent}"
                          + (f", or in {images_dir}" if images_dir is not None
                             else "; give --images FOLDER to look it up there by its name")
                          + ")" if name else "missing, and no imageData")
    height, width = doc.get("imageHeight"), doc.get("imageWidth")
    if height is not None or width is not None:
        if isinstance(height, int) and isinstance(width, int) and height > 0 and width > 0:
            frame.size_hw = (height, width)
        else:
            frame.problem("imageWidth/imageHeight", f"expected positive whole numbers, got "
                          f"{width!r} x {height!r}")
    for k, shape in enumerate(doc["shapes"]):
        where = f"shapes[{k}]"
        if not isinstance(shape, dict):
            frame.problem(where, "expected an object")
            continue
        label, kind = shape.get("label"), shape.get("shape_type") or "polygon"
        if not isinstance(label, str) or not label.strip():
            frame.problem(f"{where}.label", "missing")
            continue
        if kind in NOT_AREAS:
            frame.warn(f"{where}.shape_type", f"{kind} {label!r} has no area; left out")
            continue
        try:
            geometry = _geometry(shape, kind)
        except ValueError as exc:
            if "needs at least 3" in str(exc):
                frame.warn(f"{where}.points", f"{exc}; left out")
            else:
                part = ("mask" if kind == "mask" else "shape_type" if "shape_type" in str(exc)
                        else "points")
                frame.problem(f"{where}.{part}", str(exc))
            continue
        frame.shapes.append(Shape(label, geometry, where))
    return frame
