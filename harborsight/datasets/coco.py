"""COCO instances JSON (``images``, ``annotations``, ``categories``) -> frames to import.

``segmentation`` may be a list of polygons (``[x0, y0, x1, y1, ...]`` each, their union the
object), an uncompressed RLE (``{"size": [h, w], "counts": [n0, n1, ...]}``, column-major,
starting with a run of zeros) or a compressed RLE (``counts`` COCO's string); ``iscrowd`` RLEs
are read like any other. Polygons and RLEs are decoded with ``pycocotools``. An image's
``file_name`` is looked up under ``--images`` when given, else beside the JSON, then in
``images/`` beside it. Coordinates and drawing order: :mod:`harborsight.datasets.annotations`.
"""

from __future__ import annotations

from pathlib import Path

from harborsight.datasets.annotations import (
    AnnotationSet,
    CocoRle,
    FrameAnnotation,
    Issue,
    Polygons,
    Shape,
    compressed_rle_counts,
    find_image,
    load_json_file,
    ring_from_flat,
)
from harborsight.errors import brief


def image_bases(annotation_file: Path, images_dir: Path | None) -> list[Path]:
    """Where a COCO or CVAT file's image names are looked up: ``--images``, or the file's
    folder then ``images/`` beside it."""
    if images_dir is not None:
        return [Path(images_dir)]
    return [annotation_file.parent, annotation_file.parent / "images"]


def _rle_shape(seg: dict, size_hw: tuple[int, int] | None) -> CocoRle:
    """A checked :class:`CocoRle`; ValueError saying what is wrong."""
    size = seg.get("size")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise ValueError(f"size: expected [height, width], got {size!r}")
    if size_hw is not None and tuple(size) != size_hw:
        raise ValueError(f"size {size[1]}x{size[0]} (w x h) differs from the image entry's "
                         f"{size_hw[1]}x{size_hw[0]} (a mask of another size)")
    counts = seg.get("counts")
    if isinstance(counts, list):
        if not all(isinstance(c, int) and c >= 0 for c in counts):
            raise ValueError("counts: expected non-negative whole numbers")
        runs = counts
    elif isinstance(counts, str):
        try:
            runs = compressed_rle_counts(counts)
        except (ValueError, UnicodeEncodeError) as exc:
            raise ValueError(f"counts: not a COCO compressed RLE ({exc})") from None
        if any(c < 0 for c in runs):
            raise ValueError("counts: a negative run length")
    else:
        raise ValueError("counts: expected a list of run lengths or a compressed string")
    if sum(runs) != size[0] * size[1]:
        raise ValueError(f"counts: the runs cover {sum(runs)} pixels, size {size[1]}x{size[0]} "
                         f"has {size[0] * size[1]}")
    return CocoRle({"size": list(size), "counts": counts})


def _is_id(value: object) -> bool:
    """COCO ids are whole numbers (some tools write strings); not lists, floats or bools."""
    return isinstance(value, (int, str)) and not isinstance(value, bool)


def read_coco(sources: list[Path], images_dir: Path | None = None) -> AnnotationSet:
    """Frames of one or more COCO instances files."""
    out = AnnotationSet("coco")
    for path in sources:
        out.files.append(str(path))
        _read_file(Path(path), images_dir, out)
    return out


def _read_file(path: Path, images_dir: Path | None, out: AnnotationSet) -> None:
    doc = load_json_file(path, out.issues)
    if doc is None:
        return
    if not isinstance(doc, dict) or not isinstance(doc.get("images"), list):
        out.issues.append(Issue(str(path), "images", "not a COCO instances file (no images list)"))
        return
    if not doc["images"]:
        out.issues.append(Issue(str(path), "images", "no images: empty annotation file"))
        return
    source = str(path)
    if doc.get("categories") is not None and not isinstance(doc["categories"], list):
        # no shape's class can be known: every frame of the file is in doubt
        out.issues.append(Issue(source, "categories", "expected a list of {id, name}, got "
                                f"{brief(doc['categories'])}"))
        return
    categories = {}
    for k, cat in enumerate(doc.get("categories") or []):
        if isinstance(cat, dict) and _is_id(cat.get("id")) and isinstance(cat.get("name"), str):
            if cat["id"] in categories and categories[cat["id"]] != cat["name"]:
                # which name the annotations meant cannot be told: every shape of it is in doubt
                out.issues.append(Issue(source, f"categories[{k}].id", f"id {cat['id']!r} is used "
                                        f"twice ({categories[cat['id']]!r}, {cat['name']!r})"))
                return
            categories[cat["id"]] = cat["name"]
        else:
            out.warnings.append(Issue(source, f"categories[{k}]", "expected an id (a whole number "
                                      "or a string) and a name; left out"))
    bases = image_bases(path, images_dir)
    by_id: dict[object, FrameAnnotation] = {}
    for i, image in enumerate(doc["images"]):
        where = f"images[{i}]"
        name = image.get("file_name") if isinstance(image, dict) else None
        if not isinstance(name, str) or not name:
            out.issues.append(Issue(source, f"{where}.file_name", "missing: the image cannot be found"))
            continue
        found = find_image(name, bases)
        frame = FrameAnnotation(source, where, found or bases[0] / name.replace("\\", "/"),
                                size_field=f"{where}.width/height")
        height, width = image.get("height"), image.get("width")
        if height is not None or width is not None:
            if isinstance(height, int) and isinstance(width, int) and height > 0 and width > 0:
                frame.size_hw = (height, width)
            else:
                frame.problem(f"{where}.width/height", f"expected positive whole numbers, got "
                              f"{width!r} x {height!r}")
        if found is None:
            frame.problem(f"{where}.file_name", f"image file not found: {name} (looked in "
                          + ", ".join(str(b) for b in bases) + ")")
        if not _is_id(image.get("id")):
            frame.problem(f"{where}.id", f"expected a whole number or a string, got "
                          f"{brief(image.get('id'))}")
        elif image.get("id") in by_id:
            frame.problem(f"{where}.id", f"image id {image.get('id')!r} is used twice")
        else:
            by_id[image.get("id")] = frame
        out.frames.append(frame)
    annotations = doc.get("annotations")
    if not isinstance(annotations, list):
        out.warnings.append(Issue(source, "annotations", "missing: every image is unlabelled"))
        annotations = []
    for k, ann in enumerate(annotations):
        where = f"annotations[{k}]"
        frame = (by_id.get(ann.get("image_id")) if isinstance(ann, dict) and _is_id(ann.get("image_id"))
                 else None)
        if frame is None:
            out.warnings.append(Issue(source, f"{where}.image_id", "no image entry with id "
                                      f"{ann.get('image_id') if isinstance(ann, dict) else None!r}; "
                                      "annotation left out"))
            continue
        label = categories.get(ann.get("category_id")) if _is_id(ann.get("category_id")) else None
        if label is None:
            frame.problem(f"{where}.category_id", f"no category with id {ann.get('category_id')!r}")
            continue
        seg = ann.get("segmentation")
        if isinstance(seg, list) and seg and all(isinstance(v, (int, float)) for v in seg):
            frame.problem(f"{where}.segmentation", "expected a list of polygons [[x0, y0, x1, y1, "
                          "...], ...], got one flat list of numbers (wrap it in [ ])")
        elif isinstance(seg, list) and not seg:
            # CVAT's and Roboflow's COCO exports write a rectangle so, its shape in bbox only
            frame.problem(f"{where}.segmentation", "empty: a box-only annotation (bbox "
                          f"{brief(ann.get('bbox'))})? boxes are not masks (see harborsight "
                          "dataset label-from-boxes)")
        elif isinstance(seg, list):
            rings = []
            for r, ring in enumerate(seg):
                try:
                    rings.append(ring_from_flat(ring, "polygon"))
                except ValueError as exc:
                    if "needs at least 3" in str(exc):   # degenerate: no area to lose
                        frame.warn(f"{where}.segmentation[{r}]", f"{exc}; left out")
                    else:
                        frame.problem(f"{where}.segmentation[{r}]", str(exc))
            if rings:
                frame.shapes.append(Shape(label, Polygons(tuple(rings)), f"{where}.segmentation"))
        elif isinstance(seg, dict):
            try:
                frame.shapes.append(Shape(label, _rle_shape(seg, frame.size_hw), f"{where}.segmentation"))
            except ValueError as exc:
                frame.problem(f"{where}.segmentation", str(exc))
        else:
            frame.problem(f"{where}.segmentation", "missing: a box-only annotation? boxes are not "
                          "masks (see harborsight dataset label-from-boxes)")
