"""A labelled dataset from a box dataset: :func:`label_from_boxes` per image, the reviewer's
corrections on top, a review sheet, and the dataset layout of ``layout.py``.

Corrections (``--corrections FILE``, YAML) record what a reviewer changed after looking at
the proposals, so that the reviewed masks can be rebuilt from the boxes and the file::

    DJI_0298:                                  # image stem
      - class: obstacle                        # water, ship, obstacle or ignore
        only: [water]                          # optional: repaint only pixels of these classes
        polygon: [[1510, 700], [2047, 520], [2047, 1000], [1500, 1100]]   # pixels of the image
        why: lawn behind the rip-rap taken for water
      - class: ignore
        box: [100, 200, 300, 400]              # x0, y0, x1, y1, instead of a polygon
      - class: ship
        relabel_box: 8                         # the 9th box read (from 0; a box wholly outside
        why: a boat on the lift, no canopy     # the image is not read) is a ship box
      - class: obstacle
        line: [[20, 30], [200, 140]]           # a polyline of 2 or more points ...
        width: 6                               # ... painted this many pixels wide (a pontoon)

Polygons are in pixels of the original image (x right, y down), painted in file order with
``cv2.fillPoly`` (pixel centres inside or on the outline). A line paints the pixels whose
centres lie within half its width of the polyline (shapely's flat-capped, mitred buffer):
``width: 5`` along a row is 5 pixels across. ``relabel_box`` changes the class
of one box before the proposal is made (the box datasets box a boat on a lift as ``lift``;
the boat is a ship, the lift and its canopy are not). ``exclude: <reason>`` instead of a
list leaves the image out of the dataset, with the reason recorded in ``dataset.json``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
import yaml
from shapely import intersects_xy
from shapely.geometry import LineString, Polygon

from harborsight import __version__
from harborsight.datasets.classmap import TARGET_NAMES, class_of
from harborsight.datasets.from_boxes import BoxLabelResult, BoxLabelSettings, label_from_boxes
from harborsight.datasets.layout import CLASSES, SCHEMA
from harborsight.datasets.yolo import ImageBoxes
from harborsight.errors import InputError
from harborsight.files import strict_json, write_bytes_atomic, write_text_atomic
from harborsight.images import decode_image_file
from harborsight.perception.classes import IGNORE


@dataclass(frozen=True)
class Correction:
    class_id: int
    polygon: np.ndarray            # (N, 2) float, pixels of the original image
    only: tuple[int, ...] | None   # classes it may repaint; None: all
    why: str = ""
    band: Polygon | None = None    # a line's band (then ``polygon`` is its outline)


@dataclass
class Corrections:
    by_stem: dict[str, list[Correction]] = field(default_factory=dict)
    excluded: dict[str, str] = field(default_factory=dict)   # stem -> reason
    box_classes: dict[str, dict[int, int]] = field(default_factory=dict)  # stem -> box -> class


class _KeysAsWrittenLoader(yaml.SafeLoader):
    """Safe YAML whose map keys stay as written: YAML 1.1 reads the stem ``000123`` as the
    octal number 83 (and ``12:30`` as 750), which would miss the image silently."""

    def construct_mapping(self, node, deep=False):
        self.flatten_mapping(node)  # merge keys (<<) first
        for key, _ in node.value:
            if isinstance(key, yaml.ScalarNode):
                key.tag = "tag:yaml.org,2002:str"
        return super().construct_mapping(node, deep=deep)


def read_corrections(path: str | Path) -> Corrections:
    """Parse a corrections YAML (module docstring); :class:`InputError` names the entry."""
    path = Path(path)
    try:
        doc = yaml.load(path.read_text(), Loader=_KeysAsWrittenLoader) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(path, None, f"cannot read corrections: {exc}") from None
    if not isinstance(doc, dict):
        raise InputError(path, None, "expected a map of image stem -> list of corrections")
    result = Corrections()
    for stem, entries in doc.items():
        stem = str(stem)
        if isinstance(entries, dict) and set(entries) == {"exclude"}:
            result.excluded[stem] = str(entries["exclude"])
            continue
        if not isinstance(entries, list):
            raise InputError(path, stem, "expected a list of corrections or {exclude: reason}")
        items = []
        for k, entry in enumerate(entries):
            where = f"{stem}[{k}]"
            if not isinstance(entry, dict):
                raise InputError(path, where, "expected a map with class and polygon or box")
            cls = class_of(str(entry.get("class", "")), {})
            if cls is None:
                raise InputError(path, f"{where}.class", f"{entry.get('class')!r} is not water, "
                                 "ship, obstacle or ignore")
            if "relabel_box" in entry:
                box_index = entry["relabel_box"]
                if not isinstance(box_index, int) or isinstance(box_index, bool) or box_index < 0:
                    raise InputError(path, f"{where}.relabel_box", "expected a box number (0 first)")
                result.box_classes.setdefault(stem, {})[box_index] = cls
                continue
            band = None
            if "line" in entry:
                band = _line_band(path, where, entry["line"], entry.get("width"))
                points = np.asarray(band.exterior.coords, float)
            elif "polygon" in entry:
                points = np.asarray(entry["polygon"], float)
                if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3:
                    raise InputError(path, f"{where}.polygon", "expected 3 or more [x, y] points")
            elif "box" in entry:
                values = np.asarray(entry["box"], float).ravel()
                if values.size != 4 or values[2] <= values[0] or values[3] <= values[1]:
                    raise InputError(path, f"{where}.box", "expected [x0, y0, x1, y1] with x1 > x0, "
                                     "y1 > y0")
                x0, y0, x1, y1 = values
                points = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
            else:
                raise InputError(path, where, "needs a polygon, a box or a line")
            only = entry.get("only")
            if only is not None:
                ids = [class_of(str(name), {}) for name in only]
                if None in ids:
                    raise InputError(path, f"{where}.only", f"unknown class in {only}")
                only = tuple(ids)
            items.append(Correction(cls, points, only, str(entry.get("why", "")), band))
        result.by_stem[stem] = items
    return result


def _line_band(path: Path, where: str, line, width) -> Polygon:
    """The band within ``width / 2`` of a polyline (module docstring)."""
    points = np.asarray(line, float)
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 2:
        raise InputError(path, f"{where}.line", "expected 2 or more [x, y] points")
    if (not isinstance(width, int | float) or isinstance(width, bool) or not np.isfinite(width)
            or width < 1):
        raise InputError(path, f"{where}.width", "a line needs a width of 1 pixel or more")
    return LineString(points).buffer(width / 2, cap_style="flat", join_style="mitre")


def _pixels_in(shape: Polygon, size: tuple[int, int]) -> np.ndarray:
    """A mask of the pixels whose centres lie in ``shape`` or on its outline."""
    mask = np.zeros(size, bool)
    x0, y0, x1, y1 = shape.bounds
    cols = np.arange(max(0, int(np.ceil(x0))), min(size[1], int(np.floor(x1)) + 1))
    rows = np.arange(max(0, int(np.ceil(y0))), min(size[0], int(np.floor(y1)) + 1))
    if cols.size and rows.size:
        xs, ys = np.meshgrid(cols, rows)
        mask[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1] = intersects_xy(shape, xs, ys)
    return mask


def apply_corrections(labels: np.ndarray, corrections: list[Correction]) -> np.ndarray:
    """The labels with each correction painted in order (a copy)."""
    out = labels.copy()
    for item in corrections:
        if item.band is not None:
            paint = _pixels_in(item.band, out.shape)
        else:
            region = np.zeros(out.shape, np.uint8)
            cv2.fillPoly(region, [np.round(item.polygon).astype(np.int32)], 1)
            paint = region > 0
        if item.only is not None:
            paint &= np.isin(out, item.only)
        out[paint] = item.class_id
    return out


@dataclass
class BoxDatasetResult:
    splits: dict[str, str] = field(default_factory=dict)
    skipped: list[tuple[str, str]] = field(default_factory=list)  # (file, reason)
    notes: dict[str, list[str]] = field(default_factory=dict)
    agreement: dict[str, float] = field(default_factory=dict)     # stem -> pixel agreement


def _agreement(proposal: np.ndarray, reviewed: np.ndarray) -> float:
    """Share of pixels labelled in both (not 255) on which proposal and reviewed mask agree."""
    both = (proposal != IGNORE) & (reviewed != IGNORE)
    return float((proposal[both] == reviewed[both]).mean()) if both.any() else 1.0


#: makes a proposal from an image and its boxes
Proposer = Callable[[np.ndarray, list], BoxLabelResult]


def write_box_dataset(images: list[ImageBoxes], out_dir: str | Path, splits: dict[str, str],
                      corrections: Corrections | None = None, max_side: int | None = None,
                      settings: BoxLabelSettings | None = None,
                      on_image: Callable[[str, str | None], None] | None = None,
                      proposer: Proposer | None = None, generator: str = "label-from-boxes",
                      skipped_before: list[tuple[str, str]] | None = None) -> BoxDatasetResult:
    """Propose a mask for each image (``proposer``, by default :func:`label_from_boxes`
    with ``settings``), apply the corrections, write ``images/``, ``labels/``,
    ``proposals/`` (the masks before correction) and ``dataset.json``. ``splits`` maps every
    stem to its split. One image that fails is skipped and listed, with ``skipped_before``
    (``(file, reason)`` of inputs left out while reading them) in ``dataset.json``."""
    if proposer is None:
        def proposer(image, boxes):
            return label_from_boxes(image, boxes, settings)
    out_dir = Path(out_dir)
    corrections = corrections or Corrections()
    result = BoxDatasetResult(skipped=list(skipped_before or []))
    for sub in ("images", "labels", "proposals"):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    try:
        for item in images:
            stem = item.image_path.stem
            problem = None
            if stem in corrections.excluded:
                problem = f"excluded by the review: {corrections.excluded[stem]}"
            elif stem not in splits:
                problem = "no split given for this image"
            else:
                problem = _write_one(item, stem, out_dir, corrections, max_side, proposer, result)
            if problem is None:
                result.splits[stem] = splits[stem]
            else:
                result.skipped.append((str(item.image_path), problem))
            if on_image is not None:
                on_image(stem, problem)
    finally:
        if result.splits:
            _write_doc(out_dir, images, result, corrections, max_side, generator)
    return result


def _write_one(item: ImageBoxes, stem: str, out_dir: Path, corrections: Corrections,
               max_side: int | None, proposer: Proposer, result: BoxDatasetResult) -> str | None:
    image, incomplete = decode_image_file(item.image_path, cv2.IMREAD_COLOR)
    if incomplete:
        return incomplete
    if image is None:
        return "cannot decode image (missing, corrupt or not an image)"
    if image.shape[:2] != (item.height, item.width):
        return (f"image is {image.shape[1]}x{image.shape[0]}, the boxes were read for "
                f"{item.width}x{item.height}")
    boxes = list(item.boxes)
    for box_index, class_id in corrections.box_classes.get(stem, {}).items():
        if box_index >= len(boxes):
            return f"corrections: relabel_box {box_index} but the image has {len(boxes)} box(es)"
        boxes[box_index] = replace(boxes[box_index], class_id=class_id)
    proposal = proposer(image, boxes)
    labels = apply_corrections(proposal.labels, corrections.by_stem.get(stem, []))
    result.agreement[stem] = _agreement(proposal.labels, labels)
    result.notes[stem] = proposal.notes
    proposed = proposal.labels
    if max_side is not None and max(image.shape[:2]) > max_side:
        scale = max_side / max(image.shape[:2])
        size = (max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        labels = cv2.resize(labels, size, interpolation=cv2.INTER_NEAREST_EXACT)
        proposed = cv2.resize(proposed, size, interpolation=cv2.INTER_NEAREST_EXACT)
    ok_image, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 92])
    ok_labels, png = cv2.imencode(".png", labels)
    ok_proposal, proposal_png = cv2.imencode(".png", proposed)
    if not (ok_image and ok_labels and ok_proposal):
        return "encoding failed"
    write_bytes_atomic(out_dir / "labels" / f"{stem}.png", png.tobytes())
    write_bytes_atomic(out_dir / "proposals" / f"{stem}.png", proposal_png.tobytes())
    write_bytes_atomic(out_dir / "images" / f"{stem}.jpg", jpeg.tobytes())
    return None


def _write_doc(out_dir: Path, images: list[ImageBoxes], result: BoxDatasetResult,
               corrections: Corrections, max_side: int | None, generator: str) -> None:
    labels_used = Counter(box.label for item in images for box in item.boxes)
    class_map = {}
    for item in images:
        for box in item.boxes:
            class_map.setdefault(box.label, TARGET_NAMES[box.class_id])
    agreement = list(result.agreement.values())
    doc = {
        "schema": SCHEMA,
        "generator": f"harborsight dataset {generator} {__version__}",
        "time": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "source": {"format": "yolo-boxes" if generator == "label-from-boxes" else "images",
                   "images": sorted({str(i.image_path.parent.resolve()) for i in images})},
        "classes": CLASSES,
        "ignore_index": IGNORE,
        "class_map": dict(sorted(class_map.items())),
        "boxes_per_class_name": dict(sorted(labels_used.items())),
        "split": dict(sorted(result.splits.items())),
        "frames_without_pose": True,
        "max_side": max_side,
        "labels": f"{generator} proposals with the reviewer's corrections; proposals/ holds "
                  "the masks before correction",
        "corrections": {stem: len(items) for stem, items in sorted(corrections.by_stem.items())},
        "proposal_agreement": {
            "mean": float(np.mean(agreement)) if agreement else None,
            "per_image": {s: round(a, 5) for s, a in sorted(result.agreement.items())},
            "meaning": "share of pixels labelled in both the proposal and the reviewed mask "
                       "(neither 255) on which they agree",
        },
        "notes": {s: n for s, n in sorted(result.notes.items()) if n},
        "skipped": [{"file": f, "reason": r} for f, r in result.skipped],
    }
    write_text_atomic(out_dir / "dataset.json", strict_json(doc, indent=1) + "\n")
