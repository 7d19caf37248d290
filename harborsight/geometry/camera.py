"""Pinhole camera with OpenCV distortion: intrinsics, loaders, projection, back-projection.

A world point ``X_W`` (ENU, metres) maps to pixels by

    X_C = R_C<-W · (X_W - c_W)          (c_W: camera centre in W)
    (u, v) = K · distort(X_C / z_C)     (OpenCV model, cv2.projectPoints)

and a pixel back-projects to the ray ``c_W + t · R_W<-C · [x, y, 1]`` with ``(x, y)`` the
undistorted normalised coordinates; the ray meets the plane ``z = z_p`` at
``t = (z_p - c_z) / d_z`` when ``t > 0``.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError, brief
from harborsight.geometry.polygons import clip_to_box
from harborsight.text_formats import load_yaml_text, long_whole_number

_VALID_DISTORTION_LENGTHS = (0, 4, 5, 8, 12, 14)
#: the longest image side a calibration or a frame may state (a 100 000 px side is already
#: beyond any camera; the limit keeps a typo of 400 digits from becoming a width of 1e308)
MAX_IMAGE_SIDE_PX = 100_000
# a hull edge reaching far past the image (a point just in front of the camera plane) is cut
# into at most this many steps; its distorted part beyond the fold is refused anyway
_MAX_STEPS_PER_EDGE = 4096
# a step of an outline that crosses a barrel fold is bisected this often (to 1/32 of a step)
_FOLD_BISECTIONS = 5
_NEWTON_STEPS = 6
_NEWTON_SKIP_PX = 1e-7  # pixels that OpenCV's iteration already brought this close are left


#: a convex set reaching behind the camera is cut at this depth (m, or this share of its
#: farthest point's depth if more): what lies nearer projects beyond any image
_NEAR_DEPTH_M = 1e-3
_NEAR_DEPTH_SHARE = 1e-4


def _ahead_of_camera(points_c: np.ndarray) -> np.ndarray:
    """The part of a convex set (points in the camera frame, ``z`` along the optical axis) in
    front of the near plane ``z = n``: its points beyond it and the crossings of the plane by
    every segment from one of those to a point nearer, ``p + (n - z_p)/(z_q - z_p) (q - p)``
    (the convex hull of the set cut by the plane has its new corners on such segments).
    Dropping the points behind (as before) shrank the hull's image: a review's low, close
    view of a yacht's 20 m mast left 615 of its 5,014 pixels outside the vessel's region."""
    depth = points_c[:, 2]
    if len(points_c) == 0 or depth.max() <= 0:
        return points_c[depth > 1e-9]
    near = max(_NEAR_DEPTH_M, _NEAR_DEPTH_SHARE * float(depth.max()))
    ahead, behind = points_c[depth > near], points_c[depth <= near]
    if len(behind) == 0 or len(ahead) == 0:
        return ahead if len(ahead) else points_c[depth > 1e-9]
    if len(ahead) * len(behind) <= _MAX_NEAR_PAIRS:
        p, q = np.repeat(ahead, len(behind), axis=0), np.tile(behind, (len(ahead), 1))
    else:
        p, q = _hull_edges_across(points_c, depth > near)
    t = (near - p[:, 2]) / (q[:, 2] - p[:, 2])
    return np.vstack((ahead, p + t[:, None] * (q - p)))


#: beyond this many pairs of points either side of the near plane, only the pairs joined by
#: an edge of the set's convex hull are cut: the plane's polygon has its corners on such
#: edges. Every pair of a scanned hull's 20,737 points, 10,000 of them behind a low drone,
#: asked for 18 GB
_MAX_NEAR_PAIRS = 200_000


def _hull_edges_across(points_c: np.ndarray, ahead: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ends ``(p ahead, q behind)`` of the edges of the points' 3-D convex hull that
    cross the near plane (``ahead``: which points lie beyond it). Qhull joggles a flat set
    (``QJ``); a set it cannot hull at all is paired on every k-th point of either side, so
    that the pairs stay within :data:`_MAX_NEAR_PAIRS`."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        try:
            simplices = ConvexHull(points_c).simplices
        except QhullError:
            simplices = ConvexHull(points_c, qhull_options="QJ").simplices
    except (QhullError, ValueError):
        front, back = points_c[ahead], points_c[~ahead]
        k = math.ceil(math.sqrt(len(front) * len(back) / _MAX_NEAR_PAIRS))
        front, back = front[::k], back[::k]
        return np.repeat(front, len(back), axis=0), np.tile(back, (len(front), 1))
    edges = np.concatenate((simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [2, 0]]))
    edges = edges[ahead[edges[:, 0]] != ahead[edges[:, 1]]]
    first_ahead = ahead[edges[:, 0]]
    p = np.where(first_ahead, edges[:, 0], edges[:, 1])
    q = np.where(first_ahead, edges[:, 1], edges[:, 0])
    return points_c[p], points_c[q]


@functools.lru_cache(maxsize=64)
def fold_radius(distortion: tuple[float, ...]) -> float:
    """The undistorted radius ``r`` (normalised) at which an OpenCV model's distorted
    radius ``r (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`` stops growing
    (a barrel fold): a point there or beyond projects back inside, onto a point nearer the
    centre. Found on a grid of 1e-4 out to r = 20 (inf when the model grows that far).
    Projecting a point a little past the fold, the undistortion found it again (it converged
    to that root): a tug's hull 2.7-3.1 past a fold at 1.13 was drawn 200 px above the image
    and its outline reached there."""
    k = (list(distortion) + [0.0] * 8)[:8]
    k1, k2, _p1, _p2, k3, k4, k5, k6 = k
    r = np.linspace(0.0, 20.0, 200_001)
    r2 = r * r
    with np.errstate(divide="ignore", invalid="ignore"):
        grown = r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    stops = np.flatnonzero(~(np.diff(grown) > 0))
    return float(r[stops[0]]) if len(stops) else math.inf


def sensor_focal_px(focal_mm: float, sensor_width_mm: float, sensor_height_mm: float,
                    width: int, height: int) -> tuple[float, str]:
    """A lens's focal length in pixels of a ``width`` x ``height`` frame of its sensor, and
    the side (``"width"`` or ``"height"``) the frame spans: the width when the frame is at
    least as wide as the sensor (16:9 video from a 4:3 or 3:2 sensor), else the height (a
    4:3 photo from a 3:2 sensor, a portrait crop): ``f / side_mm · side_px``."""
    if width * sensor_height_mm >= height * sensor_width_mm:
        return focal_mm / sensor_width_mm * width, "width"
    return focal_mm / sensor_height_mm * height, "height"


@dataclass(frozen=True)
class CameraIntrinsics:
    """Image size (px), focal lengths and principal point (px), OpenCV distortion."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()

    @classmethod
    def from_sensor(
        cls,
        width: int,
        height: int,
        sensor_width_mm: float,
        sensor_height_mm: float,
        focal_length_mm: float,
        distortion: tuple[float, ...] = (),
    ) -> CameraIntrinsics:
        """``fx = f·width/sensor_width``, ``cx = (width-1)/2``, likewise for y."""
        return cls(
            width=int(width),
            height=int(height),
            fx=focal_length_mm * width / sensor_width_mm,
            fy=focal_length_mm * height / sensor_height_mm,
            cx=(width - 1) / 2.0,
            cy=(height - 1) / 2.0,
            distortion=tuple(distortion),
        )

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(abs(k) > 0.0 for k in self.distortion)

    @property
    def dist_coeffs(self) -> np.ndarray:
        return np.asarray(self.distortion if self.distortion else (0.0,) * 5, dtype=float)

    def to_dict(self) -> dict:
        return {
            "width": self.width, "height": self.height,
            "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
            "distortion": list(self.distortion) if self.distortion else [0.0] * 5,
        }

    def validate(self, source: str | Path | None, prefix: str = "camera") -> None:
        """Raise :class:`InputError` on non-finite or out-of-range values."""
        for name in ("width", "height"):
            value = getattr(self, name)
            if not (isinstance(value, int) and 0 < value <= MAX_IMAGE_SIDE_PX):
                raise InputError(source, f"{prefix}.{name}", "must be a whole number of pixels "
                                 f"from 1 to {MAX_IMAGE_SIDE_PX}, got {brief(value)}")
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise InputError(source, f"{prefix}.{name}", f"must be a positive number, got {value!r}")
        for name in ("cx", "cy"):
            value = getattr(self, name)
            if not np.isfinite(value):
                raise InputError(source, f"{prefix}.{name}", f"must be finite, got {value!r}")
        if len(self.distortion) not in _VALID_DISTORTION_LENGTHS:
            raise InputError(
                source, f"{prefix}.distortion",
                f"OpenCV takes 4, 5, 8, 12 or 14 coefficients, got {len(self.distortion)}",
            )
        if not all(np.isfinite(self.distortion)):
            raise InputError(source, f"{prefix}.distortion", "coefficients must be finite")


def _matrix_from_ros(node: object, path: Path, key: str, shape: tuple[int, int] | None
                     ) -> np.ndarray:
    """A ROS ``{rows, cols, data}`` matrix; ``shape`` (when given) is the one it must have."""
    what = "expected {rows, cols, data}"
    if not isinstance(node, dict):
        raise InputError(path, key, f"{what}, got {brief(node)}")
    rows, cols = (_whole(node.get(name), path, f"{key}.{name}", 1, 64) for name in ("rows", "cols"))
    raw = node.get("data")
    if raw is None:
        raise InputError(path, f"{key}.data", "missing")
    try:
        data = np.asarray(raw, dtype=float)
    except OverflowError:               # a whole number of 400 digits
        raise InputError(path, f"{key}.data", "holds a number too large to be finite") from None
    except (TypeError, ValueError):
        bad = next(((i, v) for i, v in enumerate(raw, 1)
                    if isinstance(v, bool) or not isinstance(v, (int, float))), None
                   ) if isinstance(raw, list) else None
        if bad is None:
            raise InputError(path, f"{key}.data", f"expected a list of numbers, got {brief(raw)}"
                             ) from None
        raise InputError(path, f"{key}.data", f"element {bad[0]} is not a number: {brief(bad[1])}"
                         ) from None
    if data.ndim != 1 or data.size != rows * cols:
        raise InputError(path, f"{key}.data", f"expected {rows * cols} numbers ({rows}x{cols}), "
                         f"got {data.size if data.ndim == 1 else 'a nested list'}")
    if shape is not None and (rows, cols) != shape:
        raise InputError(path, key, f"expected a {shape[0]}x{shape[1]} matrix, got {rows}x{cols}")
    return data.reshape(rows, cols)


def _whole(value: object, path: Path, key: str, low: int, high: int) -> int:
    """A whole number from ``low`` to ``high`` (a float such as 640.0 is taken too)."""
    if isinstance(value, float) and value.is_integer() and low <= value <= high:
        value = int(value)
    if value is None:
        raise InputError(path, key, "missing")
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InputError(path, key, f"expected a whole number from {low} to {high}, "
                         f"got {brief(value)}")
    return value


def _distortion_shape_ok(rows: int, cols: int) -> bool:
    return min(rows, cols) == 1 and rows * cols in _VALID_DISTORTION_LENGTHS


def _load_ros_camera_info(doc: dict, path: Path) -> CameraIntrinsics:
    """ROS ``camera_info`` YAML (camera_calibration_parsers): K in ``camera_matrix``."""
    K = _matrix_from_ros(doc["camera_matrix"], path, "camera_matrix", (3, 3))
    dist = doc.get("distortion_coefficients")
    coeffs = _matrix_from_ros(dist, path, "distortion_coefficients", None).ravel() if dist else []
    model = doc.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise InputError(path, "distortion_model", f"{brief(model)} is not an OpenCV pinhole model")
    return CameraIntrinsics(
        width=_whole(doc.get("image_width"), path, "image_width", 1, MAX_IMAGE_SIDE_PX),
        height=_whole(doc.get("image_height"), path, "image_height", 1, MAX_IMAGE_SIDE_PX),
        fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2]),
        distortion=tuple(float(c) for c in coeffs),
    )


#: OpenCV's one-channel element types (``dt``): 8U, 8S, 16U, 16S, 32S, 32F, 64F, 16F
_FILESTORAGE_TYPES = set("ucwsifdh")
#: OpenCV's FileStorage parser wraps a whole number past 2**31 and corrupts its own state
#: with one past 2**32: any of this many digits is refused before OpenCV reads the file
_FILESTORAGE_MAX_DIGITS = 9


def _describe_node(node) -> str:
    """A FileStorage node's value for a message."""
    if node.empty():
        return "nothing"
    if node.isInt() or node.isReal():
        return f"{node.real():g}"
    if node.isString():
        return brief(node.string())
    return "a sequence" if node.isSeq() else "a mapping" if node.isMap() else "an unknown value"


def _filestorage_matrix(node, path: Path, key: str, allowed, wanted: str) -> np.ndarray:
    """An ``!!opencv-matrix`` node, checked before OpenCV reads it: ``rows``, ``cols``,
    ``dt`` and the length and numbers of ``data`` (``node.mat()`` asserts on a mismatch and
    allocates what ``rows`` says: 51 GB for ``rows: three``). ``allowed(rows, cols)`` says
    whether the shape fits; ``wanted`` words it."""
    if not node.isMap():
        raise InputError(path, key, f"expected an opencv-matrix {{rows, cols, dt, data}}, "
                         f"got {_describe_node(node)}")
    dims = []
    for name in ("rows", "cols"):
        child = node.getNode(name)
        if not child.isInt() or not 1 <= child.real() <= 64:
            raise InputError(path, f"{key}.{name}", f"expected a whole number from 1 to 64 "
                             f"({wanted}), got {_describe_node(child)}")
        dims.append(int(child.real()))
    rows, cols = dims
    if not allowed(rows, cols):
        raise InputError(path, key, f"expected {wanted}, got {rows}x{cols}")
    dt = node.getNode("dt")
    if not dt.isString() or dt.string() not in _FILESTORAGE_TYPES:
        raise InputError(path, f"{key}.dt", "expected one of " + ", ".join(sorted(
            _FILESTORAGE_TYPES)) + f" (d: 64-bit float), got {_describe_node(dt)}")
    data = node.getNode("data")
    if not data.isSeq():
        raise InputError(path, f"{key}.data", f"expected a list of {rows * cols} numbers, got "
                         f"{_describe_node(data)}")
    if data.size() != rows * cols:
        raise InputError(path, f"{key}.data", f"expected {rows * cols} numbers ({rows}x{cols}), "
                         f"got {data.size()}")
    for i in range(data.size()):
        item = data.at(i)
        if not (item.isInt() or item.isReal()):
            raise InputError(path, f"{key}.data", f"element {i + 1} is not a number: "
                             f"{_describe_node(item)}")
    matrix = node.mat()
    if matrix is None or matrix.size != rows * cols:
        raise InputError(path, key, f"OpenCV could not read it as {wanted}")
    return np.asarray(matrix, dtype=float).reshape(rows, cols)


def _filestorage_whole(node, path: Path, key: str) -> int:
    if not node.isInt() or not 1 <= node.real() <= MAX_IMAGE_SIDE_PX:
        raise InputError(path, key, f"expected a whole number of pixels from 1 to "
                         f"{MAX_IMAGE_SIDE_PX}, got {_describe_node(node)}")
    return int(node.real())


def _check_filestorage_numbers(text: str, path: Path) -> None:
    """Refuse whole numbers OpenCV cannot hold (:data:`_FILESTORAGE_MAX_DIGITS`)."""
    found = long_whole_number(text, _FILESTORAGE_MAX_DIGITS + 1)
    if found is not None:
        field, line, shown = found
        raise InputError(path, field, f"{shown} on line {line} is too large a whole number for an "
                         f"OpenCV FileStorage file (more than {_FILESTORAGE_MAX_DIGITS} digits)")


#: deepest nesting passed to OpenCV's FileStorage parser, which recurses without a limit and
#: crashes the process (a segmentation fault, not an exception) on a few thousand levels; a
#: calibration file nests three deep
_FILESTORAGE_MAX_DEPTH = 32
_XML_TAG = re.compile(r"<(/?)[A-Za-z_][\w.:-]*[^<>]*?(/?)>")


def filestorage_nesting_depth(text: str) -> tuple[int, int]:
    """The deepest nesting in YAML or XML text and the line where it is reached: flow
    brackets ``[`` ``{`` (outside quotes), block indentation levels, and XML elements."""
    deepest, where, flow, quote = 0, 1, 0, ""
    indents: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.lstrip(" ")
        if stripped and not stripped.startswith("#") and not quote and flow == 0:
            width = len(line) - len(stripped)
            while indents and width < indents[-1]:
                indents.pop()
            if not indents or width > indents[-1]:
                indents.append(width)
        for char in line:
            if quote:
                quote = "" if char == quote else quote
            elif char in "\"'":
                quote = char
            elif char in "[{":
                flow += 1
            elif char in "]}":
                flow = max(0, flow - 1)
            if len(indents) + flow > deepest:
                deepest, where = len(indents) + flow, number
        quote = ""                      # YAML quotes do not span lines in these files
    depth, deepest_at = 0, None
    for match in _XML_TAG.finditer(text):
        depth += -1 if match[1] else (0 if match[2] else 1)
        if depth > deepest:
            deepest, deepest_at = depth, match.start()
    if deepest_at is not None:          # the line counted once: per tag it was quadratic
        where = text.count("\n", 0, deepest_at) + 1
    return deepest, where


#: the lens models harborsight's camera is (OpenCV's pinhole with radial and tangential terms)
PINHOLE_MODELS = ("plumb_bob", "rational_polynomial", "radtan", "radial-tangential", "pinhole")


def _check_filestorage_model(fs, path: Path) -> None:
    """Refuse a FileStorage calibration of another lens model: OpenCV's fisheye calibration
    (``fisheye_model: 1`` in its calibration sample's output) or a ``distortion_model`` such
    as ``equidistant``. Its four coefficients would otherwise be read as k1, k2, p1, p2, and
    a fisheye's edge rays would be 15-20 % off."""
    fisheye = fs.getNode("fisheye_model")
    if not fisheye.empty() and (fisheye.isInt() or fisheye.isReal()) and fisheye.real() != 0:
        raise InputError(path, "fisheye_model", "a fisheye calibration (OpenCV's "
                         "cv::fisheye model); harborsight's camera is the pinhole model with "
                         f"radial and tangential distortion ({', '.join(PINHOLE_MODELS[:2])})")
    model = fs.getNode("distortion_model")
    if model.empty():
        return
    name = model.string() if model.isString() else None
    if name is None or name.strip().lower() not in PINHOLE_MODELS:
        shown = repr(name) if name is not None else "not a name"
        raise InputError(path, "distortion_model", f"{shown} is not a pinhole model "
                         f"harborsight reads ({', '.join(PINHOLE_MODELS)})")


def _load_opencv_filestorage(path: Path, text: str) -> CameraIntrinsics:
    """cv2.FileStorage YAML/XML as written by OpenCV's calibration sample."""
    _check_filestorage_numbers(text, path)
    depth, line = filestorage_nesting_depth(text)
    if depth > _FILESTORAGE_MAX_DEPTH:
        raise InputError(path, f"line {line}", f"nested {depth} levels deep: more than "
                         f"{_FILESTORAGE_MAX_DEPTH}, which OpenCV's FileStorage parser cannot "
                         "read safely (a calibration file nests 3 deep)")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:     # a parse error comes wrapped in a SystemError
        cause = exc if isinstance(exc, cv2.error) else exc.__cause__ or exc.__context__ or exc
        raise InputError(path, None, "not a FileStorage file OpenCV can read: "
                         f"{_cv_message(cause)}") from None
    if not fs.isOpened():
        raise InputError(path, None, "cannot open as an OpenCV FileStorage file")
    field_name = None
    try:
        def first(*names: str):
            for name in names:
                node = fs.getNode(name)
                if not node.empty():
                    return name, node
            return None, None

        field_name = "camera_matrix"
        k_name, k_node = first("camera_matrix", "cameraMatrix", "K", "intrinsics")
        if k_node is None:
            raise InputError(path, "camera_matrix", "missing (also tried cameraMatrix, K)")
        field_name = k_name
        K = _filestorage_matrix(k_node, path, k_name, lambda r, c: (r, c) == (3, 3),
                                "a 3x3 matrix")
        field_name = "distortion_model"
        _check_filestorage_model(fs, path)
        field_name = "distortion_coefficients"
        d_name, d_node = first("distortion_coefficients", "dist_coeffs", "distCoeffs", "D")
        if d_node is None:
            dist = ()
        else:
            field_name = d_name
            dist = tuple(float(c) for c in _filestorage_matrix(
                d_node, path, d_name, _distortion_shape_ok,
                "a row or column of 4, 5, 8, 12 or 14 coefficients").ravel())
        field_name = "image_width"
        w_name, w_node = first("image_width", "imageWidth")
        h_name, h_node = first("image_height", "imageHeight")
        if w_node is None or h_node is None:
            field_name = "image_size"
            s_name, size_node = first("image_size", "imageSize")
            if size_node is None:
                raise InputError(path, "image_width", "missing image_width/image_height")
            field_name = s_name
            if size_node.isSeq():
                if size_node.size() != 2:
                    raise InputError(path, s_name, f"expected [width, height], got "
                                     f"{size_node.size()} values")
                width, height = (_filestorage_whole(size_node.at(i), path, s_name) for i in (0, 1))
            else:
                size = _filestorage_matrix(size_node, path, s_name,
                                           lambda r, c: r * c == 2 and min(r, c) == 1,
                                           "[width, height]").ravel()
                if not all(v.is_integer() and 1 <= v <= MAX_IMAGE_SIDE_PX for v in size):
                    raise InputError(path, s_name, f"expected whole numbers of pixels from 1 to "
                                     f"{MAX_IMAGE_SIDE_PX}, got {size.tolist()}")
                width, height = int(size[0]), int(size[1])
        else:
            width = _filestorage_whole(w_node, path, w_name)
            field_name = h_name
            height = _filestorage_whole(h_node, path, h_name)
    except cv2.error as exc:            # OpenCV asserts on what the checks above did not foresee
        raise InputError(path, field_name, f"OpenCV cannot read it: {_cv_message(exc)}") from None
    finally:
        fs.release()
    return CameraIntrinsics(
        width=width, height=height, fx=float(K[0, 0]), fy=float(K[1, 1]),
        cx=float(K[0, 2]), cy=float(K[1, 2]), distortion=dist,
    )


def _check_utf8(data: bytes, path: Path) -> None:
    """Refuse a FileStorage file that is not UTF-8: OpenCV reads it, and a field holding a
    byte such as 0xe9 (Latin-1) raises UnicodeDecodeError when its value is read back."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(path, f"line {line}", f"not UTF-8 text (byte 0x{data[exc.start]:02x}): "
                         "save the file as UTF-8") from None


def _cv_message(exc: BaseException) -> str:
    """The reason in an OpenCV error, without its source file: 'line 5: Incorrect
    indentation' for a parse error."""
    text = " ".join(str(exc).split())
    if (m := re.search(r"\((\d+)\): ([^']*)'?\s*$", text)) is not None:
        text = f"line {m[1]}: {m[2].strip()}"
    elif (m := re.search(r"error: \(-?\d+:[^)]*\) (.*)", text)) is not None:
        text = m[1]
    return text if len(text) <= 120 else text[:117] + "..."


def load_camera_calibration(path: str | Path) -> CameraIntrinsics:
    """Load intrinsics from an OpenCV FileStorage (YAML/XML) or a ROS camera_info YAML."""
    path = Path(path)
    if path.is_dir():
        raise InputError(path, None, "is a folder, not a file (expected a calibration file)")
    if not path.is_file():
        raise InputError(path, None, "calibration file not found")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    text = data.decode("utf-8", errors="replace")
    if path.suffix.lower() == ".xml" or text.lstrip().startswith("%YAML"):
        _check_utf8(data, path)         # OpenCV hands its strings back as UTF-8
        intrinsics = _load_opencv_filestorage(path, text)
    else:
        doc = load_yaml_text(text, path)
        if not isinstance(doc, dict) or "camera_matrix" not in doc:
            raise InputError(path, "camera_matrix", "missing: not a ROS camera_info file")
        intrinsics = _load_ros_camera_info(doc, path)
    intrinsics.validate(path, prefix="calibration")
    return intrinsics


@dataclass(frozen=True)
class Camera:
    """A posed camera: intrinsics plus centre ``position_enu`` and ``R_W<-C``."""

    intrinsics: CameraIntrinsics
    position_enu: np.ndarray
    world_from_camera: np.ndarray = field(repr=False)

    @property
    def camera_from_world(self) -> np.ndarray:
        return self.world_from_camera.T

    def to_camera_frame(self, points_enu: np.ndarray) -> np.ndarray:
        """``X_C = R_C<-W · (X_W - c_W)`` for points of shape ``(N, 3)``."""
        return (np.asarray(points_enu, float) - self.position_enu) @ self.world_from_camera

    def project(self, points_enu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project ENU points ``(N, 3)`` to pixels ``(N, 2)``.

        Returns ``(uv, in_front)``; points at or behind the camera plane get NaN pixels.
        So do points beyond the radius where a strongly barrel-distorted model stops growing
        (``r·(1 + k1·r² + ...)`` turns back): ``cv2.projectPoints`` folds them back into the
        image, so a projection whose undistortion does not return the point is refused.
        """
        pts_c = self.to_camera_frame(np.atleast_2d(points_enu))
        in_front = pts_c[:, 2] > 1e-9
        uv = np.full((len(pts_c), 2), np.nan)
        if not np.any(in_front):
            return uv, in_front
        front = pts_c[in_front]
        intr = self.intrinsics
        if intr.has_distortion:
            projected, _ = cv2.projectPoints(
                front.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs
            )
            projected = projected.reshape(-1, 2)
            ideal = front[:, :2] / front[:, 2:3]
            recovered = self._undistorted(projected)
            with np.errstate(invalid="ignore"):
                folded = ~(np.hypot(*(recovered - ideal).T)
                           <= 1e-6 * (1.0 + np.hypot(*ideal.T)))
            # the undistortion can land back on a point past the fold (another root of
            # the model): that the model still grows there is checked on its own
            folded |= np.hypot(*ideal.T) >= fold_radius(intr.distortion)
            projected[folded] = np.nan
            uv[in_front] = projected
            in_front[np.flatnonzero(in_front)[folded]] = False
        else:
            uv[in_front, 0] = intr.fx * front[:, 0] / front[:, 2] + intr.cx
            uv[in_front, 1] = intr.fy * front[:, 1] / front[:, 2] + intr.cy
        return uv, in_front

    def project_convex_outline(self, points_enu: np.ndarray, max_step_px: float = 4.0) -> np.ndarray:
        """Pixels ``(M, 2)`` along the image outline of the convex hull of ``points_enu``.

        A pinhole maps the solid's convex hull to the 2-D convex hull of its projected
        vertices, so without distortion that polygon's corners are returned. Lens distortion
        then bends each straight edge (barrel: outward, by up to several px near the image
        corners for ``k1 ≈ -0.25``), so the hull of the projected corners alone would cut
        the curve. The edges are therefore cut, in undistorted normalised coordinates
        ``(x/z, y/z)``, into steps of at most ``max_step_px`` before distorting, and the
        convex hull of the result follows a barrel-bent edge: the chord of a step ``s`` on a
        curve of radius ``R`` falls ``s^2 / 8R`` short, 0.004 px for 4 px steps on a box
        near the corner of a 90-degree lens with ``k1 = -0.2`` (0.0002 px for 1 px steps, at
        four times the cost; 0.055 px for 16 px).
        Points at or behind the camera plane, and points past a fold, are left out.
        """
        return self.project_convex_outlines([points_enu], max_step_px)[0]

    def project_convex_outlines(self, point_sets: list[np.ndarray], max_step_px: float = 4.0
                                ) -> list[np.ndarray]:
        """:meth:`project_convex_outline` of several point sets (a vessel's layers) at once:
        one projection for all of them, the edges of every set's hull cut into steps
        together."""
        # each set's part in front of the camera (a mast above a low drone reaches behind it)
        sets_c = [_ahead_of_camera(self.to_camera_frame(np.atleast_2d(points)))
                  for points in point_sets]
        if not self.intrinsics.has_distortion:
            sizes = [len(pts_c) for pts_c in sets_c]
            every_c = np.vstack(sets_c) if sets_c else np.zeros((0, 3))
            uv, front = self.project(every_c @ self.world_from_camera.T + self.position_enu)
            return [self._within_reach(u[f]) for u, f in zip(
                np.split(uv, np.cumsum(sizes)[:-1]), np.split(front, np.cumsum(sizes)[:-1]),
                strict=True)]
        step = max_step_px / max(self.intrinsics.fx, self.intrinsics.fy)
        corners, following, owner = [], [], []
        for k, pts_c in enumerate(sets_c):
            pts_c = pts_c[pts_c[:, 2] > 1e-9]
            if len(pts_c) == 0:
                continue
            ideal = pts_c[:, :2] / pts_c[:, 2:3]
            if len(ideal) >= 3:
                ideal = ideal[cv2.convexHull(ideal.astype(np.float32), returnPoints=False).reshape(-1)]
            corners.append(ideal)
            following.append(np.concatenate((ideal[1:], ideal[:1])))
            owner.append(np.full(len(ideal), k))
        out = [np.zeros((0, 2)) for _ in point_sets]
        if not corners:
            return out
        corners, following, owner = np.vstack(corners), np.vstack(following), np.concatenate(owner)
        n_steps = np.clip(np.ceil(np.hypot(*(following - corners).T) / step), 1,
                          _MAX_STEPS_PER_EDGE).astype(int)
        edge = np.repeat(np.arange(len(corners)), n_steps)
        t = np.arange(len(edge)) - np.repeat(np.cumsum(n_steps) - n_steps, n_steps)
        t = (t / n_steps[edge])[:, None]
        dense = corners[edge] * (1.0 - t) + following[edge] * t
        uv, front = self._project_ideal(dense)
        dense_owner = owner[edge]
        # where an outline leaves the lens model (past a barrel fold), the steps would stop up
        # to a step short of the edge of what projects: bisect each such step to its end
        following_sample = np.concatenate((np.arange(1, len(dense)), [0]))
        first_of_set = np.r_[0, np.flatnonzero(np.diff(dense_owner)) + 1]
        last_of_set = np.r_[first_of_set[1:], len(dense)] - 1
        following_sample[last_of_set] = first_of_set           # each set's outline is closed
        change = np.flatnonzero(front != front[following_sample])
        if len(change):
            inside = np.where(front[change, None], dense[change], dense[following_sample[change]])
            outside = np.where(front[change, None], dense[following_sample[change]], dense[change])
            for _ in range(_FOLD_BISECTIONS):
                middle = 0.5 * (inside + outside)
                _, ok = self._project_ideal(middle)
                inside[ok], outside[~ok] = middle[ok], middle[~ok]
            end_uv, end_ok = self._project_ideal(inside)
            uv = np.vstack((uv, end_uv))
            front = np.concatenate((front, end_ok))
            dense_owner = np.concatenate((dense_owner, dense_owner[change]))
        for k in np.unique(dense_owner):
            mine = (dense_owner == k) & front
            out[k] = self._within_reach(uv[mine])
        return out

    def _within_reach(self, uv: np.ndarray) -> np.ndarray:
        """Pixels of a convex outline, its hull clipped to the image grown by four times its
        size on every side where it reaches farther (a part just in front of the camera
        projects millions of pixels out): the image's part of it is the same."""
        intr = self.intrinsics
        w, h = intr.width, intr.height
        if len(uv) < 3 or ((uv > [-4 * w, -4 * h]) & (uv < [5 * w, 5 * h])).all():
            return uv
        hull = uv[cv2.convexHull(uv.astype(np.float32), returnPoints=False).reshape(-1)]
        return clip_to_box(hull, -4.0 * w, -4.0 * h, 5.0 * w, 5.0 * h)

    def _project_ideal(self, ideal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`project` of the rays through undistorted normalised coordinates ``(N, 2)``."""
        rays_c = np.column_stack((ideal, np.ones(len(ideal))))
        return self.project(rays_c @ self.world_from_camera.T + self.position_enu)

    def _undistorted(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised coordinates of pixels ``(N, 2)``: OpenCV's fixed-point
        iteration, then Newton steps on ``K · distort(x, y) = uv``.

        The fixed-point iteration contracts by roughly ``1 - r_d'(r)`` per step, so near a
        barrel model's fold (``r_d' → 0``) it crawls: with ``k1 = -0.2`` a point 3 % inside
        the fold is still 1e-3 (0.4 px) off after 40 steps. Newton's step
        ``δ = J⁻¹ (uv - K · distort(x, y))`` uses the 2x2 Jacobian that ``cv2.projectPoints``
        gives for the translation (a shift of the point ``(x, y, 1)`` is a shift of ``(x, y)``);
        a step that does not reduce the residual is not taken.
        """
        intr = self.intrinsics
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
        xy = cv2.undistortPointsIter(
            uv.reshape(-1, 1, 2), intr.K, intr.dist_coeffs, None, None, criteria
        ).reshape(-1, 2).astype(float)
        projected, _ = cv2.projectPoints(np.column_stack((xy, np.ones(len(xy)))).reshape(-1, 1, 3),
                                         np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
        with np.errstate(invalid="ignore"):
            slow = np.isfinite(xy).all(axis=1) & ~(
                np.abs(projected.reshape(-1, 2) - uv).max(axis=1) <= _NEWTON_SKIP_PX)
        if slow.any():
            xy[slow] = self._newton_polished(xy[slow], uv[slow])
        return xy

    def _newton_polished(self, xy: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Newton steps on ``K · distort(x, y) = uv`` from ``xy``; see :meth:`_undistorted`."""
        residual_px, jacobian = self._distortion_residual(xy, uv)
        for _ in range(_NEWTON_STEPS):
            a, b, c, d = jacobian[:, 0, 0], jacobian[:, 0, 1], jacobian[:, 1, 0], jacobian[:, 1, 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                det = a * d - b * c
                step = np.column_stack((d * residual_px[:, 0] - b * residual_px[:, 1],
                                        a * residual_px[:, 1] - c * residual_px[:, 0])) / det[:, None]
            trial = xy - np.where(np.isfinite(step), step, 0.0)
            trial_residual, trial_jacobian = self._distortion_residual(trial, uv)
            with np.errstate(invalid="ignore"):
                better = (np.hypot(*trial_residual.T) < np.hypot(*residual_px.T))
            if not better.any():
                break
            xy[better] = trial[better]
            residual_px[better] = trial_residual[better]
            jacobian[better] = trial_jacobian[better]
        return xy

    def _distortion_residual(self, xy: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``K · distort(x, y) - uv`` ``(N, 2)`` and its Jacobian by ``(x, y)`` ``(N, 2, 2)``."""
        intr = self.intrinsics
        rays = np.column_stack((xy, np.ones(len(xy)))).reshape(-1, 1, 3)
        projected, jacobian = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), intr.K,
                                                intr.dist_coeffs)
        residual = projected.reshape(-1, 2) - uv
        # columns 3:6 of OpenCV's Jacobian are d(u, v)/d(tvec); rows alternate u, v
        return residual, jacobian[:, 3:5].reshape(-1, 2, 2)

    def normalized_coordinates(self, uv: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates ``(x, y)`` of pixels ``(N, 2)``; NaN for
        a pixel the distortion model cannot invert (beyond a strongly barrel-distorted
        model's fold, the iteration stops at a point that does not project back to it)."""
        uv = np.atleast_2d(np.asarray(uv, float))
        intr = self.intrinsics
        if len(uv) == 0:
            return np.zeros((0, 2))
        if intr.has_distortion:
            xy = self._undistorted(uv)
            back, _ = cv2.projectPoints(np.column_stack((xy, np.ones(len(xy)))).reshape(-1, 1, 3),
                                        np.zeros(3), np.zeros(3), intr.K, intr.dist_coeffs)
            with np.errstate(invalid="ignore"):
                xy[~(np.hypot(*(back.reshape(-1, 2) - uv).T) <= 0.01)] = np.nan
            return xy
        return np.column_stack(((uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy))

    def plane_homography(self, plane_z_m: float = 0.0) -> np.ndarray:
        """3x3 ``H`` mapping undistorted normalised coordinates ``m = (x, y, 1)`` to the
        homogeneous point where the ray meets the plane ``z = z_p``.

        With ``r_i`` the rows of ``R_W<-C`` and ``c`` the camera centre, the ray
        ``c + t · R m`` meets the plane at ``t = (z_p - c_z) / (r_3 · m)``, so

            (X, Y) = (c_x·(r_3·m) + (z_p - c_z)·(r_1·m),  c_y·(r_3·m) + (z_p - c_z)·(r_2·m)) / (r_3·m)

        i.e. ``H = [c_x r_3 + (z_p - c_z) r_1; c_y r_3 + (z_p - c_z) r_2; r_3]``. The hit is
        in front of the camera when ``(z_p - c_z) / (r_3 · m) > 0``.
        """
        R = self.world_from_camera
        c = self.position_enu
        dz = plane_z_m - c[2]
        return np.vstack((c[0] * R[2] + dz * R[0], c[1] * R[2] + dz * R[1], R[2]))

    def pixels_to_plane_xy(
        self, uv: np.ndarray, plane_z_m: float = 0.0, post: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Plane coordinates ``(N, 2)`` of pixels, optionally mapped by a 3x3 ``post``
        (e.g. world -> vessel frame); returns ``(xy, valid)``, NaN where invalid."""
        m = self.normalized_coordinates(uv)
        H = self.plane_homography(plane_z_m)
        # the unmapped homography's last row is the ray's vertical component r_3 · m
        down = m[:, 0] * H[2, 0] + m[:, 1] * H[2, 1] + H[2, 2]
        if post is not None:
            H = post @ H
        dz = plane_z_m - self.position_enu[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            valid = np.isfinite(down) & (dz / down > 0)
            w = m[:, 0] * H[2, 0] + m[:, 1] * H[2, 1] + H[2, 2]
            xy = np.column_stack((m[:, 0] * H[0, 0] + m[:, 1] * H[0, 1] + H[0, 2],
                                  m[:, 0] * H[1, 0] + m[:, 1] * H[1, 1] + H[1, 2])) / w[:, None]
        xy[~valid] = np.nan
        return xy, valid

    def back_project_to_plane(
        self, uv: np.ndarray, plane_z_m: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """Intersect pixel rays with the horizontal plane ``z = plane_z_m``.

        Returns ``(points_enu (N, 3), valid (N,))``; rays that point at or above the
        horizon (no intersection in front of the camera) are invalid and NaN.
        """
        xy, valid = self.pixels_to_plane_xy(uv, plane_z_m)
        points = np.column_stack((xy, np.full(len(xy), float(plane_z_m))))
        points[~valid] = np.nan
        return points, valid

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """True where a pixel lies inside the image (pixel centres at integers)."""
        uv = np.atleast_2d(uv)
        w, h = self.intrinsics.width, self.intrinsics.height
        with np.errstate(invalid="ignore"):
            return (
                np.isfinite(uv).all(axis=1)
                & (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5)
                & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
            )
