"""CVAT for images 1.1 XML (``annotations.xml``) -> frames to import.

Each ``<image name= width= height=>`` holds shapes, each with ``label`` and ``z_order``:
``<polygon points="x,y;x,y;...">``, ``<box xtl= ytl= xbr= ybr= [rotation=]>``,
``<ellipse cx= cy= rx= ry= [rotation=]>`` (rotation in degrees, clockwise on the picture,
about the shape's centre) and ``<mask rle= left= top= width= height=>`` (CVAT's run lengths:
row-major over the ``width`` x ``height`` patch whose top-left pixel is ``(left, top)``,
alternating runs of 0 and 1 beginning with 0). ``<polyline>``, ``<points>``, ``<skeleton>``
and ``<cuboid>`` have no area and are left out with a warning; ``<tag>`` is ignored. Image
names are looked up under ``--images`` when given, else beside the XML, then in ``images/``
beside it (CVAT's export archive). Coordinates and drawing order:
:mod:`harborsight.datasets.annotations`.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

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
    rectangle,
    ring_from_flat,
)
from harborsight.datasets.coco import image_bases

NOT_AREAS = ("polyline", "points", "skeleton", "cuboid")


def _number(el: ET.Element, name: str) -> float:
    text = el.get(name)
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number, got {text!r}") from None
    if not np.isfinite(value):
        raise ValueError(f"{name}: expected a finite number, got {text!r}")
    return value


def _whole(el: ET.Element, name: str, minimum: int) -> int:
    value = _number(el, name)
    if value != int(value) or value < minimum:
        raise ValueError(f"{name}: expected a whole number >= {minimum}, got {el.get(name)!r}")
    return int(value)


def decode_cvat_rle(text: str, width: int, height: int) -> np.ndarray:
    """The boolean ``height`` x ``width`` patch of a CVAT mask's ``rle``; ValueError if the
    runs are not whole numbers covering exactly ``width * height`` pixels."""
    try:
        runs = [int(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise ValueError(f"rle: expected comma-separated run lengths, got {text[:40]!r}") from None
    if any(r < 0 for r in runs):
        raise ValueError("rle: a negative run length")
    if sum(runs) != width * height:
        raise ValueError(f"rle: the runs cover {sum(runs)} pixels, the {width}x{height} patch has "
                         f"{width * height} (a mask of another size)")
    values = np.arange(len(runs)) % 2 == 1
    return np.repeat(values, runs).reshape(height, width)


def _geometry(el: ET.Element):
    tag = el.tag
    if tag == "polygon":
        text = el.get("points") or ""
        try:
            flat = [float(v) for pair in text.split(";") if pair.strip() for v in pair.split(",")]
        except ValueError:
            raise ValueError(f"points: expected x,y;x,y;..., got {text[:40]!r}") from None
        return Polygons((ring_from_flat(flat, "points"),))
    angle = _number(el, "rotation") if el.get("rotation") is not None else 0.0
    if tag == "box":
        return rectangle(_number(el, "xtl"), _number(el, "ytl"), _number(el, "xbr"),
                         _number(el, "ybr"), angle)
    if tag == "ellipse":
        return Ellipse(_number(el, "cx"), _number(el, "cy"), _number(el, "rx"), _number(el, "ry"),
                       angle)
    if tag == "mask":
        width, height = _whole(el, "width", 1), _whole(el, "height", 1)
        return Bitmap(decode_cvat_rle(el.get("rle") or "", width, height),
                      _whole(el, "left", -(10**9)), _whole(el, "top", -(10**9)))
    raise AssertionError(tag)


def read_cvat(sources: list[Path], images_dir: Path | None = None) -> AnnotationSet:
    """Frames of CVAT for images 1.1 XML files."""
    out = AnnotationSet("cvat")
    for path in sources:
        path = Path(path)
        out.files.append(str(path))
        _read_file(path, images_dir, out)
    return out


def _read_file(path: Path, images_dir: Path | None, out: AnnotationSet) -> None:
    source = str(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        out.issues.append(Issue(source, None, f"cannot read: {exc.strerror or exc}"))
        return
    if not data.strip():
        out.issues.append(Issue(source, None, "empty annotation file (0 bytes)"))
        return
    try:
        root = ET.fromstring(data)
    except (ET.ParseError, LookupError, ValueError) as exc:   # LookupError: an unknown encoding
        out.issues.append(Issue(source, None, f"invalid XML: {exc}"))
        return
    if root.tag != "annotations":
        out.issues.append(Issue(source, root.tag, "not a CVAT XML file (root is not <annotations>)"))
        return
    images = root.findall("image")
    if not images:
        hint = (" (CVAT for video: export as CVAT for images 1.1)" if root.find("track") is not None
                else "")
        out.issues.append(Issue(source, "image", f"no <image> elements: empty annotation file{hint}"))
        return
    bases = image_bases(path, images_dir)
    for i, image in enumerate(images):
        name = image.get("name")
        where = f"image[{i}]" + (f"[name={name}]" if name else "")
        if not name:
            out.issues.append(Issue(source, f"{where}.name", "missing: the image cannot be found"))
            continue
        found = find_image(name, bases)
        frame = FrameAnnotation(source, where, found or bases[0] / name.replace("\\", "/"),
                                size_field=f"{where}.width/height")
        if found is None:
            frame.problem(f"{where}.name", f"image file not found: {name} (looked in "
                          + ", ".join(str(b) for b in bases) + ")")
        if image.get("width") is not None or image.get("height") is not None:
            try:
                frame.size_hw = (_whole(image, "height", 1), _whole(image, "width", 1))
            except ValueError as exc:
                frame.problem(f"{where}.width/height", str(exc))
        counts: dict[str, int] = {}
        for el in image:
            k = counts[el.tag] = counts.get(el.tag, -1) + 1
            at = f"{where}.{el.tag}[{k}]"
            if el.tag == "tag":
                continue
            label = el.get("label")
            if el.tag in NOT_AREAS:
                frame.warn(at, f"{el.tag} {label!r} has no area; left out")
                continue
            if el.tag not in ("polygon", "box", "ellipse", "mask"):
                frame.warn(at, f"unknown element <{el.tag}>; left out")
                continue
            if not label or not label.strip():
                frame.problem(f"{at}.label", "missing")
                continue
            try:
                z_order = float(el.get("z_order") or 0)
                if not (math.isfinite(z_order) and z_order == int(z_order)):
                    raise ValueError
            except ValueError:
                frame.problem(f"{at}.z_order", f"expected a whole number, got {el.get('z_order')!r}")
                continue
            try:
                z_order = int(z_order)
                geometry = _geometry(el)
            except ValueError as exc:
                if "needs at least 3" in str(exc):
                    frame.warn(f"{at}.points", f"{exc}; left out")
                else:
                    frame.problem(at, str(exc))
                continue
            frame.shapes.append(Shape(label, geometry, at, z_order))
        out.frames.append(frame)
