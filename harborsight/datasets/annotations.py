"""Annotated shapes, the frames they belong to, and how they become a class mask.

Coordinates. Every format's coordinates are read as continuous image positions in pixels,
x right and y down, with pixel ``(row i, column j)`` covering ``[j, j+1) x [i, i+1)``: its
centre is at ``(j + 0.5, i + 0.5)`` and the whole image spans ``[0, W] x [0, H]``. This is
what COCO, CVAT, LabelMe (a click's position on the picture) and YOLO (``x * W``) mean.
(harborsight's own image frame, OpenCV's, puts pixel centres on integers: ``u = x - 0.5``.)

Rasterisation. A polygon (and a rectangle, which is a four-corner polygon) covers the pixels
that COCO's rasteriser assigns to it (``pycocotools.mask.frPyObjects``: along axis-aligned
edges exactly the pixels whose centres lie inside, along slanted edges that rule up to a pixel
here and there); one rasteriser for every format, so a polygon means the same pixels whatever
tool drew it. Circles and ellipses cover
the pixels whose centres lie inside. Bitmaps (COCO RLE, CVAT and LabelMe masks) are taken
pixel for pixel.

Drawing order. The mask starts as the background (water, 0; or ignore, 255), then the shapes
paint their class in order: ascending ``z_order`` (CVAT; 0 elsewhere), ties in file order, so a
later shape paints over an earlier one. A class mapped to ``ignore`` paints 255 like any other
class: it hides what lies under it and is hidden by what comes later.

Parts outside the image are cut off at the image edge (the shape's other pixels are kept); the
importer reports such a shape as a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from harborsight.errors import InputError
from harborsight.files import is_existing_file
from harborsight.geometry.polygons import clip_to_box
from harborsight.text_formats import parse_json_text


@dataclass(frozen=True)
class Issue:
    """A problem with one input: the file, the field in it (None: the file as a whole), what
    is wrong. ``str()`` gives the one-line ``file: field: reason``."""

    file: str
    field: str | None
    reason: str

    def __str__(self) -> str:
        return ": ".join(p for p in (self.file, self.field, self.reason) if p)

    def to_dict(self) -> dict:
        return {"file": self.file, "field": self.field, "reason": self.reason}


def compressed_rle_counts(text: str | bytes) -> list[int]:
    """The run lengths of COCO's compressed RLE string (pycocotools' ``rleFrString``); a
    ValueError for a character that is not part of the code or a cut-off number."""
    counts: list[int] = []
    data = text.encode("ascii") if isinstance(text, str) else bytes(text)
    p = 0
    while p < len(data):
        x, k, more = 0, 0, True
        while more:
            if p >= len(data):
                raise ValueError("cut off in the middle of a number")
            c = data[p] - 48
            if c < 0 or c > 63:
                raise ValueError(f"character {chr(data[p])!r} is not COCO RLE")
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and c & 0x10:
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


def _paint_runs(canvas: np.ndarray, counts: list[int], value: int) -> None:
    """Paint the 1-runs of a column-major RLE (zeros first) into a Fortran-ordered canvas."""
    if not canvas.flags.f_contiguous:
        raise ValueError("the canvas must be Fortran-ordered (a column-major RLE paints it)")
    flat = canvas.ravel(order="F")   # a view of the canvas
    pos = 0
    for k, n in enumerate(counts):
        if k % 2 and n:
            flat[pos:pos + n] = value
        pos += n


#: a ring reaching this many image sides beyond the image is clipped before pycocotools
FAR_OUTSIDE = 4


class _Geometry:
    """What every geometry does: ``paint(canvas, value)`` into a Fortran-ordered uint8
    canvas of the image's size, and ``rasterise(height, width)`` as a boolean mask; its
    ``box(height, width)`` (x0, y0, x1, y1 in pixels) tells whether it reaches outside the
    image or lies wholly outside it."""

    def rasterise(self, height: int, width: int) -> np.ndarray:
        canvas = np.zeros((height, width), np.uint8, order="F")
        self.paint(canvas, 1)
        return np.ascontiguousarray(canvas, dtype=bool)

    def box(self, height: int, width: int) -> tuple[float, float, float, float]:
        raise NotImplementedError

    def outside(self, height: int, width: int) -> bool:
        x0, y0, x1, y1 = self.box(height, width)
        return x0 < 0 or y0 < 0 or x1 > width or y1 > height

    def wholly_outside(self, height: int, width: int) -> bool:
        x0, y0, x1, y1 = self.box(height, width)
        return x1 <= 0 or y1 <= 0 or x0 >= width or y0 >= height


@dataclass(frozen=True)
class Polygons(_Geometry):
    """One or more rings (each ``(N, 2)`` x, y, N >= 3) whose union is the shape; with
    ``normalised``, x and y are fractions of the image's width and height (YOLO)."""

    rings: tuple[np.ndarray, ...]
    normalised: bool = False

    def pixels(self, height: int, width: int) -> list[np.ndarray]:
        scale = np.array([width, height], np.float64) if self.normalised else 1.0
        with np.errstate(over="ignore"):    # a fraction of 1e307 is inf pixels: refused later
            return [np.asarray(ring, np.float64) * scale for ring in self.rings]

    def box(self, height: int, width: int) -> tuple[float, float, float, float]:
        pts = np.concatenate(self.pixels(height, width))
        return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()),
                float(pts[:, 1].max()))

    def reach(self) -> float:
        """The farthest coordinate from the image's origin, as the shape gives it (fractions
        of the image's size for YOLO's)."""
        return float(np.abs(np.concatenate(self.rings)).max())

    def paint(self, canvas: np.ndarray, value: int) -> None:
        """COCO's rasterisation on the whole image (pycocotools' result depends on the
        canvas: a crop around the shape would not give the same pixels), painted run by run.
        A ring reaching far beyond the image (a typo of 4e8 for 40) is first clipped to the
        image grown by a pixel, which leaves its pixels as they were: pycocotools sums
        the edges' lengths in an int, and such a ring crashed the process."""
        from pycocotools import mask as coco_mask

        height, width = canvas.shape
        far = FAR_OUTSIDE * max(height, width)
        rings = [ring if np.abs(ring).max() < far else clip_to_box(ring, -1, -1, width + 1, height + 1)
                 for ring in self.pixels(height, width)]
        rings = [ring for ring in rings if len(ring) >= 3]
        if not rings:
            return
        rles = coco_mask.frPyObjects([ring.ravel().tolist() for ring in rings], height, width)
        _paint_runs(canvas, compressed_rle_counts(coco_mask.merge(rles)["counts"]), value)


@dataclass(frozen=True)
class CocoRle(_Geometry):
    """A COCO run-length encoding (``{"size": [h, w], "counts": ...}``; counts a list, or
    COCO's compressed string), checked to cover exactly ``size`` pixels."""

    rle: dict

    @property
    def size_hw(self) -> tuple[int, int]:
        return int(self.rle["size"][0]), int(self.rle["size"][1])

    def box(self, height: int, width: int) -> tuple[float, float, float, float]:
        return 0.0, 0.0, float(width), float(height)      # its size is the image's, checked

    def paint(self, canvas: np.ndarray, value: int) -> None:
        """Through pycocotools (``frPyObjects`` for a list of counts), run by run."""
        from pycocotools import mask as coco_mask

        rle = self.rle
        if isinstance(rle["counts"], list):
            rle = coco_mask.frPyObjects(rle, *self.size_hw)
        _paint_runs(canvas, compressed_rle_counts(rle["counts"]), value)


@dataclass(frozen=True)
class Bitmap(_Geometry):
    """A boolean patch whose pixel ``[0, 0]`` is image pixel ``(top, left)``."""

    mask: np.ndarray
    left: int
    top: int

    def box(self, height: int, width: int) -> tuple[float, float, float, float]:
        h, w = self.mask.shape
        return float(self.left), float(self.top), float(self.left + w), float(self.top + h)

    def paint(self, canvas: np.ndarray, value: int) -> None:
        height, width = canvas.shape
        h, w = self.mask.shape
        y0, x0 = max(self.top, 0), max(self.left, 0)
        y1, x1 = min(self.top + h, height), min(self.left + w, width)
        if y0 < y1 and x0 < x1:
            patch = self.mask[y0 - self.top:y1 - self.top, x0 - self.left:x1 - self.left]
            canvas[y0:y1, x0:x1][patch] = value


@dataclass(frozen=True)
class Ellipse(_Geometry):
    """Centre ``(cx, cy)``, semi-axes ``rx`` along x and ``ry`` along y before a rotation of
    ``angle_deg`` (clockwise on the picture, as CVAT turns shapes) about the centre."""

    cx: float
    cy: float
    rx: float
    ry: float
    angle_deg: float = 0.0

    def box(self, height: int, width: int) -> tuple[float, float, float, float]:
        r = max(self.rx, self.ry)
        return self.cx - r, self.cy - r, self.cx + r, self.cy + r

    def paint(self, canvas: np.ndarray, value: int) -> None:
        """The pixels whose centres lie inside (or on) the ellipse."""
        height, width = canvas.shape
        r = max(self.rx, self.ry)
        i0, i1 = max(int(np.floor(self.cy - r)), 0), min(int(np.ceil(self.cy + r)) + 1, height)
        j0, j1 = max(int(np.floor(self.cx - r)), 0), min(int(np.ceil(self.cx + r)) + 1, width)
        if i0 >= i1 or j0 >= j1 or self.rx <= 0 or self.ry <= 0:
            return
        dy, dx = np.mgrid[i0:i1, j0:j1].astype(np.float64)
        dx += 0.5 - self.cx
        dy += 0.5 - self.cy
        a = np.deg2rad(self.angle_deg)   # into the ellipse's own axes: rotate back by -a
        u = dx * np.cos(a) + dy * np.sin(a)
        v = -dx * np.sin(a) + dy * np.cos(a)
        canvas[i0:i1, j0:j1][(u / self.rx) ** 2 + (v / self.ry) ** 2 <= 1.0] = value


Geometry = Polygons | CocoRle | Bitmap | Ellipse


def rectangle(x0: float, y0: float, x1: float, y1: float, angle_deg: float = 0.0) -> Polygons:
    """The box between two corners (any order), turned ``angle_deg`` clockwise about its
    centre (CVAT's rotated boxes), as a four-corner polygon."""
    xa, xb, ya, yb = min(x0, x1), max(x0, x1), min(y0, y1), max(y0, y1)
    corners = np.array([[xa, ya], [xb, ya], [xb, yb], [xa, yb]], np.float64)
    if angle_deg:
        centre = corners.mean(axis=0)
        a = np.deg2rad(angle_deg)
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        corners = (corners - centre) @ rot.T + centre
    return Polygons((corners,))


@dataclass(frozen=True)
class Shape:
    """One annotated region: the annotation's own class name, its geometry, its drawing
    order and where it sits in its file (``field``, for messages)."""

    label: str
    geometry: Geometry
    field: str
    z_order: int = 0


@dataclass
class FrameAnnotation:
    """What an annotation file says about one image, before the image is read.

    ``problems`` make the frame unusable (it is skipped and reported); ``warnings`` are
    reported but the frame is imported. ``size_hw`` is the image size the file states, if it
    states one; ``image_data`` an image embedded in the file (LabelMe's ``imageData``), used
    when ``image_path`` does not exist."""

    source: str
    where: str
    image_path: Path | None
    size_hw: tuple[int, int] | None = None
    shapes: list[Shape] = field(default_factory=list)
    problems: list[Issue] = field(default_factory=list)
    warnings: list[Issue] = field(default_factory=list)
    image_data: bytes | None = None
    #: the field that states the image size, for messages
    size_field: str = "width/height"
    #: why the frame is skipped when it has no shapes (unless unlabelled frames are kept)
    unlabelled_reason: str = "no annotated regions (an unlabelled image)"

    @property
    def stem(self) -> str:
        return self.image_path.stem if self.image_path is not None else ""

    def problem(self, field_name: str | None, reason: str) -> None:
        self.problems.append(Issue(self.source, field_name, reason))

    def warn(self, field_name: str | None, reason: str) -> None:
        self.warnings.append(Issue(self.source, field_name, reason))


def paint_labels(shapes: list[Shape], class_ids: list[int], height: int, width: int,
                 background: int) -> tuple[np.ndarray, list[int]]:
    """The uint8 class mask of ``shapes`` (``class_ids[k]`` the class of ``shapes[k]``) on a
    ``height`` x ``width`` canvas of ``background``, in the drawing order of the module doc,
    and the indices of the shapes of which no pixel is left (painted over whole by later
    ones, or smaller than a pixel). Each shape paints its index + 1; the classes are looked
    up after."""
    canvas = np.zeros((height, width), np.uint16 if len(shapes) < 65535 else np.int32, order="F")
    order = sorted(range(len(shapes)), key=lambda k: shapes[k].z_order)   # stable: file order
    for k in order:
        shapes[k].geometry.paint(canvas, k + 1)
    shown = np.zeros(len(shapes) + 1, bool)
    shown[np.unique(canvas)] = True
    lookup = np.array([background, *class_ids], np.uint8)
    return np.ascontiguousarray(lookup[canvas]), [k for k in range(len(shapes)) if not shown[k + 1]]


@dataclass
class AnnotationSet:
    """What one format's reader found: frames to import, the files that gave none (empty,
    unreadable, not of this format) as ``issues``, and ``warnings`` that belong to no frame."""

    format: str
    files: list[str] = field(default_factory=list)
    frames: list[FrameAnnotation] = field(default_factory=list)
    issues: list[Issue] = field(default_factory=list)
    warnings: list[Issue] = field(default_factory=list)


def find_image(name: str, bases: list[Path]) -> Path | None:
    """The first ``base / name`` that is a file (``name`` relative, ``/`` or ``\\`` separated;
    an absolute ``name`` is taken as it is), or None."""
    name = str(name).replace("\\", "/")
    if Path(name).is_absolute():
        return Path(name) if is_existing_file(name) else None
    for base in bases:
        if is_existing_file(base / name):
            return base / name
    return None


def ring_from_flat(values, what: str) -> np.ndarray:
    """An ``(N, 2)`` float ring from ``[x0, y0, x1, y1, ...]``; ValueError saying why if the
    numbers are not finite, odd in count, or fewer than three points."""
    try:
        pts = np.asarray(values, dtype=np.float64).ravel()
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{what}: expected numbers") from None
    if pts.size % 2:
        raise ValueError(f"{what}: an odd count of coordinates ({pts.size})")
    if not np.isfinite(pts).all():
        raise ValueError(f"{what}: a coordinate is not a finite number")
    if pts.size < 6:
        raise ValueError(f"{what}: {pts.size // 2} point(s); a polygon needs at least 3")
    return pts.reshape(-1, 2)


def load_json_file(path: Path, issues: list[Issue]) -> object | None:
    """The parsed JSON of ``path``, or None after adding an :class:`Issue` for an unreadable,
    empty (0 bytes) or invalid file."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        issues.append(Issue(str(path), None, f"cannot read: {exc.strerror or exc}"))
        return None
    if not data.strip():
        issues.append(Issue(str(path), None, "empty annotation file (0 bytes)" if not data
                            else "empty annotation file (only blanks)"))
        return None
    try:
        return parse_json_text(data.decode("utf-8-sig"), path)
    except UnicodeDecodeError as exc:
        issues.append(Issue(str(path), None, f"not valid JSON: {exc}"))
    except InputError as exc:       # bad syntax, nesting too deep, a number too long to read
        issues.append(Issue(str(path), exc.field, exc.message))
    return None
