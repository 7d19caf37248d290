"""Camera calibration files: intrinsics from an OpenCV FileStorage (YAML or XML, as
``cv2.FileStorage`` writes them) or a ROS ``camera_info`` YAML, each field checked and a
problem named by file and key (:class:`~harborsight.errors.InputError`) before OpenCV sees
it: FileStorage's own parser aborts on deep nesting and on numbers it cannot hold."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError, brief
from harborsight.geometry.camera import MAX_IMAGE_SIDE_PX, VALID_DISTORTION_LENGTHS, CameraIntrinsics
from harborsight.text_formats import load_yaml_text, long_whole_number


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
    return min(rows, cols) == 1 and rows * cols in VALID_DISTORTION_LENGTHS


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
