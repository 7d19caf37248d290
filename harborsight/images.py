"""Image files that decode but are not whole.

libjpeg decodes a JPEG cut short by filling the missing rows with grey, and OpenCV returns it
without complaint; a segmenter then calls the grey obstacle and a 3 m clearance reads 0.4 m.
So before an image is used, its container is checked for completeness, without decoding:

* JPEG: the file ends with the End Of Image marker ``FF D9`` (trailing NUL padding allowed);
* PNG: the chunks run from the signature to ``IEND``, each with its CRC-32 right;
* TIFF: Pillow reads every strip or tile (a truncated strip raises).

A frame to be measured must also hold the camera's own pixels: a picture stored turned, with
an EXIF Orientation from 2 to 8, is turned back as it is read (OpenCV does for JPEG and PNG),
and the frame's intrinsics and attitude no longer describe it. With Orientation 3 the size is
the same, so nothing else would notice: the hull lands on the wrong side of the picture and a
0.7 m contact reads clear. ``read_image(path, camera_pixels=True)`` refuses such a file.

``read_image`` and ``read_mask`` are the readers every part uses (measuring, training,
evaluation, ``segment``); they live here, not in ``harborsight.pipeline``, so that training on
a machine without the geodesy and mesh libraries needs none of the clearance stack.
"""

from __future__ import annotations

import contextlib
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np

from harborsight.errors import InputError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: OpenCV's limit on a decoded image (CV_IO_MAX_IMAGE_PIXELS' default, 2^30 pixels)
MAX_DECODED_PIXELS = 1 << 30
#: the EXIF tag of the picture's orientation (1: stored as the camera saw it)
EXIF_ORIENTATION_TAG = 0x0112


def incomplete_reason(data: bytes) -> str | None:
    """Why the encoded image ``data`` is not whole (a message that begins "cannot decode
    image:"), or None when it is (or when it is of a kind not checked here)."""
    reason = _reason(data)
    return None if reason is None else f"cannot decode image: {reason}"


def _reason(data: bytes) -> str | None:
    if data[:3] == b"\xff\xd8\xff":
        if data.rstrip(b"\x00").endswith(b"\xff\xd9") or _jpeg_end(data) is not None:
            return None         # whole (what follows its end: a phone's trailer, a motion clip)
        return "JPEG cut short: no End Of Image marker (FF D9) at the end of its data"
    if data[:8] == PNG_SIGNATURE:
        return _png_reason(data)
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff_reason(data)
    return None


def _jpeg_end(data: bytes) -> int | None:
    """Where a JPEG's End Of Image marker ends, found by walking its segments (each skipped
    by its length; in entropy-coded data ``FF 00`` and the restart markers ``FF D0``-``D7``
    are data): None when the data end first. A file may go on after it (a Samsung trailer,
    a motion photo's clip)."""
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:                       # fill byte
            pos += 1
            continue
        if marker == 0xD9:
            return pos + 2
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            pos += 2
            continue
        (length,) = struct.unpack(">H", data[pos + 2:pos + 4])
        pos += 2 + length
        if marker == 0xDA:                       # scan data up to the next real marker
            while True:
                pos = data.find(b"\xff", pos)
                if pos < 0 or pos + 1 >= len(data):
                    return None
                following = data[pos + 1]
                if following == 0x00 or 0xD0 <= following <= 0xD7:
                    pos += 2
                    continue
                break
    return None


def _png_reason(data: bytes) -> str | None:
    if data[12:16] != b"IHDR":
        return "PNG signature without an IHDR chunk after it (corrupt or not a PNG)"
    offset = 8
    while offset + 12 <= len(data):
        length, kind = struct.unpack(">I4s", data[offset:offset + 8])
        end = offset + 12 + length
        if end > len(data):
            return f"PNG cut short inside its {kind.decode('latin-1')!r} chunk"
        (crc,) = struct.unpack(">I", data[end - 4:end])
        if zlib.crc32(data[offset + 4:end - 4]) != crc:
            return f"PNG corrupt: CRC of its {kind.decode('latin-1')!r} chunk at byte {offset} is wrong"
        if kind == b"IEND":
            return None
        offset = end
    return "PNG cut short: no IEND chunk"


@contextlib.contextmanager
def _pillow_opened(data: bytes):
    """Pillow's image of ``data``, without Pillow's pixel limit: a large orthomosaic is no
    decompression bomb (its size is checked against OpenCV's own limit instead)."""
    import io

    from PIL import Image

    limit = Image.MAX_IMAGE_PIXELS
    Image.MAX_IMAGE_PIXELS = None
    try:
        with Image.open(io.BytesIO(data)) as image:
            yield image
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def _tiff_reason(data: bytes) -> str | None:
    from PIL import UnidentifiedImageError

    try:
        with _pillow_opened(data) as image:
            width, height = image.size
            if width * height > MAX_DECODED_PIXELS:
                return (f"{width}x{height} = {width * height} px, more than OpenCV decodes "
                        f"({MAX_DECODED_PIXELS}): cut it into tiles first")
            for frame in range(getattr(image, "n_frames", 1)):
                image.seek(frame)
                image.load()
    except UnidentifiedImageError:
        return None             # a kind Pillow does not read (32-bit float): OpenCV decides
    except (OSError, ValueError, SyntaxError, struct.error, MemoryError) as exc:
        return f"TIFF incomplete or corrupt: {exc}"
    return None


def exif_orientation(data: bytes) -> int | None:
    """The EXIF Orientation of the encoded image ``data`` (JPEG, TIFF, PNG, WebP), or None
    when it has none or cannot be read."""
    import io

    from PIL import Image

    if data[:8] == PNG_SIGNATURE and b"eXIf" not in data:
        return None             # Pillow would decode the whole PNG looking for the chunk
    try:
        with Image.open(io.BytesIO(data)) as image:
            value = image.getexif().get(EXIF_ORIENTATION_TAG)
    except Exception:  # Pillow raises many kinds on odd files; OpenCV decides on those
        return None
    return int(value) if isinstance(value, int) else None


def turned_reason(data: bytes) -> str | None:
    """Why the encoded image ``data`` does not hold the camera's own pixels (an EXIF
    Orientation other than 1), or None."""
    orientation = exif_orientation(data)
    if orientation not in range(2, 9):      # 1: as stored; 0 and 9+: not defined, not turned
        return None
    return (f"EXIF Orientation {orientation}: the picture is stored turned (OpenCV turns a "
            "JPEG or PNG back as it reads it), so which way the camera saw it, as the frame's "
            "intrinsics and attitude describe it, is unknown; save the camera's pixels with "
            "Orientation 1")


def decode_as_displayed(data: bytes, flags: int) -> np.ndarray | None:
    """``cv2.imdecode``, the picture turned by its EXIF Orientation as viewers and annotation
    tools show it (LabelMe, Ultralytics): OpenCV does so for JPEG, PNG and TIFF but not for
    WebP, whose masks then lay 180 degrees off (or were refused for their size)."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None
    if (image is None or data[:4] != b"RIFF" or data[8:12] != b"WEBP"
            or flags & cv2.IMREAD_IGNORE_ORIENTATION):
        return image
    return turned_as_displayed(image, exif_orientation(data))


def turned_as_displayed(image: np.ndarray, orientation: int | None) -> np.ndarray:
    """A picture as stored, turned as its EXIF ``orientation`` says it is displayed."""
    if orientation in (2, 4):
        return cv2.flip(image, 1 if orientation == 2 else 0)
    if orientation in (3, 6, 8):
        return cv2.rotate(image, {3: cv2.ROTATE_180, 6: cv2.ROTATE_90_CLOCKWISE,
                                  8: cv2.ROTATE_90_COUNTERCLOCKWISE}[orientation])
    if orientation in (5, 7):           # across the main diagonal; 7: and half a turn
        image = np.ascontiguousarray(np.swapaxes(image, 0, 1))
        return cv2.rotate(image, cv2.ROTATE_180) if orientation == 7 else image
    return image


#: the first bytes of a TIFF or BigTIFF, in either byte order
TIFF_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
#: Pillow modes with an alpha band (a TIFF's band 4 is one only where its ExtraSamples say so:
#: Pillow opens an RGB+NIR TIFF as RGBX, not RGBA)
_ALPHA_MODES = frozenset({"RGBA", "RGBa", "LA", "La", "PA"})


def may_hold_alpha(data: bytes) -> bool:
    """Whether an encoded image can carry transparency: a PNG with an alpha channel (IHDR
    colour type 4 or 6) or a ``tRNS`` chunk before its image data, any TIFF or WebP; a JPEG
    cannot."""
    if data[:8] == PNG_SIGNATURE:
        if len(data) > 25 and data[25] in (4, 6):
            return True
        image_data = data.find(b"IDAT")
        return b"tRNS" in data[:image_data if image_data > 0 else len(data)]
    return data[:4] in TIFF_MAGIC or (data[:4] == b"RIFF" and data[8:12] == b"WEBP")


#: the TIFF tag in which GDAL writes a raster's no-data value (ASCII, e.g. "0" or "-9999")
GDAL_NODATA_TAG = 42113


def no_data_pixels(data: bytes, shape: tuple[int, int]) -> np.ndarray | None:
    """Where the encoded image ``data`` holds no picture: pixels of alpha 0, as an orthophoto
    or a rectified frame marks the area outside its footprint (stored black, white or
    anything), and in a GeoTIFF pixels whose every colour band holds its ``GDAL_NODATA``
    value (as GDAL reads it: a pure black pixel of a raster whose no-data is 0 is one);
    bool (H, W) turned as the picture is displayed, or None where every pixel holds data.
    ``shape`` is the displayed picture's (H, W); a mask of another shape raises
    ``ValueError``.

    The alpha band is Pillow's, turned by :func:`PIL.ImageOps.exif_transpose` as OpenCV
    turns the colours: grey+alpha, palette and colour-key transparency (``tRNS``) come
    through it, and a TIFF's fourth band counts as alpha only where its ExtraSamples say so
    (an RGB+NIR TIFF's near-infrared, near 0 over water, is not). The no-data value is
    compared on OpenCV's decoding of the bands, which its TIFF reader turns itself."""
    no_data = _transparent(data)
    nodata_value = _gdal_nodata(data)
    if nodata_value is not None:
        stored = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if stored is not None:
            bands = stored.reshape(stored.shape[0], stored.shape[1], -1)
            colour = bands[..., :3] if bands.shape[2] == 4 else bands
            valueless = np.all(colour == nodata_value, axis=2)
            if no_data is not None and no_data.shape != valueless.shape:
                raise ValueError(f"its transparency is {no_data.shape[1]}x{no_data.shape[0]} "
                                 f"but its bands {valueless.shape[1]}x{valueless.shape[0]}")
            no_data = valueless if no_data is None else no_data | valueless
    if no_data is None or not no_data.any():
        return None
    if no_data.shape != tuple(shape):
        raise ValueError(f"its no-data mask is {no_data.shape[1]}x{no_data.shape[0]} but the "
                         f"picture {shape[1]}x{shape[0]}")
    return no_data


def _transparent(data: bytes) -> np.ndarray | None:
    """Pixels of alpha 0, turned as displayed (:func:`no_data_pixels`), or None."""
    if not may_hold_alpha(data):
        return None
    from PIL import ImageOps

    try:
        with _pillow_opened(data) as image:
            if image.mode not in _ALPHA_MODES and "transparency" not in image.info:
                return None
            shown = ImageOps.exif_transpose(image)
            alpha = np.asarray(shown.convert("RGBA").getchannel("A"))
    except Exception:  # Pillow raises many kinds on odd files; OpenCV decides on those
        return None
    return alpha == 0


def _gdal_nodata(data: bytes) -> float | None:
    """A GeoTIFF's no-data value (its ``GDAL_NODATA`` tag), or None."""
    if data[:4] not in TIFF_MAGIC:
        return None
    try:
        with _pillow_opened(data) as image:           # only its header is read
            text = image.tag_v2.get(GDAL_NODATA_TAG)
        value = float(str(text).strip().rstrip("\x00"))
    except Exception:  # no tag, or one that is not a number ("nan" is one: never equal)
        return None
    return value if np.isfinite(value) else None


def decode_image_file(path: Path, flags: int, camera_pixels: bool = False
                      ) -> tuple[np.ndarray | None, str | None]:
    """The file at ``path`` read once, checked by :func:`incomplete_reason` (and with
    ``camera_pixels`` by :func:`turned_reason`), then decoded by OpenCV with ``flags`` (EXIF
    orientation applied as ``cv2.imread`` does). Returns ``(image, None)``, ``(None,
    reason)`` for an incomplete or turned file, or ``(None, None)`` when it cannot be read
    or decoded."""
    data, reason = _checked_bytes(path, camera_pixels)
    if data is None or reason:
        return None, reason
    return decode_as_displayed(data, flags), None


def _checked_bytes(path: Path, camera_pixels: bool) -> tuple[bytes | None, str | None]:
    """The file's bytes (None where it cannot be read) and why they are not a whole image
    as stored (:func:`incomplete_reason`, with ``camera_pixels`` :func:`turned_reason`)."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None, None
    return data, incomplete_reason(data) or (turned_reason(data) if camera_pixels else None)


def read_image(path: Path, camera_pixels: bool = False) -> np.ndarray:
    """BGR image; a clear error for a missing or unreadable file, and with
    ``camera_pixels`` (a frame to be measured) for one stored turned (module docstring).
    Pixels marked as holding no picture (alpha 0) come as they are stored; see
    :func:`read_image_and_no_data`."""
    return _read_image_data(path, camera_pixels)[0]


def read_image_and_no_data(path: Path, camera_pixels: bool = False
                           ) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`read_image` and where the picture holds no data (:func:`no_data_pixels`, None
    where it all does); those pixels are black in the image. Their stored colour is often
    black and may be anything (white, the last tile's); a segmenter reads them as something,
    water most often, and a transparent corner read as water is clearance that was never
    seen. Callers label them 255 (ignore), which measuring counts as solid. Black is the
    fill that changed the other pixels' labels least among black, white, the picture's mean
    colour and the nearest pixel's, measured with the default model on 12 marina and 12
    lake-shore val frames with a 21 % triangle blanked (docs/results.md, "No-data pixels")."""
    image, data = _read_image_data(path, camera_pixels)
    try:
        no_data = no_data_pixels(data, image.shape[:2])
    except ValueError as exc:
        raise InputError(path, None, str(exc)) from None
    if no_data is not None:
        image = image.copy()
        image[no_data] = 0
    return image, no_data


def _read_image_data(path: Path, camera_pixels: bool) -> tuple[np.ndarray, bytes]:
    if path.is_dir():
        raise InputError(path, None, "is a folder, not an image file")
    if not path.is_file():
        raise InputError(path, None, "image file not found")
    data, reason = _checked_bytes(path, camera_pixels)   # a cut JPEG decodes half grey
    if data is None:
        raise InputError(path, None, "cannot read image file")
    if reason:
        raise InputError(path, "Orientation" if reason.startswith("EXIF") else None, reason)
    image = decode_as_displayed(data, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if image is None:
        raise InputError(path, None, "cannot decode image (corrupt or not an image)")
    if image.dtype == np.uint16:
        return eight_bit(image), data
    if image.dtype != np.uint8:       # floating-point samples: OpenCV's own conversion
        image = decode_as_displayed(data, cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(path, None, "cannot decode image (corrupt or not an image)")
    return image, data


def eight_bit(image: np.ndarray) -> np.ndarray:
    """A 16-bit image as 8-bit by its own bit depth: the fewest bits that hold its largest
    value (at least 8), scaled to 0-255. A camera's 10- or 12-bit samples stored in 16 bits
    are 0-4095; OpenCV's 8-bit decoding divides by 256 and leaves them 0-15, near black (a
    model then read 97 % of such a frame as water). A file does not say its samples'
    depth: an image darker than its depth (its largest value needing fewer bits) comes out
    brighter, the safer mistake for a segmentation."""
    bits = max(8, int(image.max()).bit_length())
    scale = 255.0 / ((1 << bits) - 1)
    return cv2.convertScaleAbs(image, alpha=scale)


def read_mask(path: Path) -> np.ndarray:
    """One-channel uint8 label mask (a grey PNG saved as RGB is accepted if channels agree)."""
    if path.is_dir():
        raise InputError(path, "mask", "is a folder, not a mask file")
    if not path.is_file():
        raise InputError(path, "mask", "mask file not found")
    mask, reason = decode_image_file(path, cv2.IMREAD_UNCHANGED)
    if reason:
        raise InputError(path, "mask", reason)
    if mask is None:
        raise InputError(path, "mask", "cannot decode mask (corrupt or not an image)")
    if mask.ndim == 3:
        if mask.shape[2] >= 3 and np.array_equal(mask[..., 0], mask[..., 1]) and np.array_equal(
            mask[..., 1], mask[..., 2]
        ):
            mask = mask[..., 0]
        else:
            raise InputError(path, "mask", f"expected one channel of class ids, got {mask.shape[2]}")
    return mask
