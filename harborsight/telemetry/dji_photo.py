"""DJI still photos: the pose, camera and capture time a DJI JPEG carries in its XMP and EXIF.

Every DJI photo holds an XMP packet in the ``drone-dji`` namespace
(``http://www.dji.com/drone-dji/1.0/``) beside its EXIF. Fields read (all optional, each
firmware writes a different subset, as attributes of ``rdf:Description`` or as elements):

* position: ``GpsLatitude``, ``GpsLongitude`` or the misspelt ``GpsLongtitude`` (older
  firmware); else EXIF's GPS block (degrees, minutes, seconds and N/S/E/W references);
* altitude: ``RelativeAltitude`` (barometric, above the take-off point) and
  ``AbsoluteAltitude`` (its datum depends on the model: mean sea level on most, the
  ellipsoid on RTK models; DJI's manuals say so per model);
* attitude: ``GimbalYawDegree``/``GimbalPitchDegree``/``GimbalRollDegree`` (the camera, NED
  ZYX Euler angles, pitch −90° straight down: the convention of ``harborsight.frame/1``) and
  ``FlightYawDegree``/``...Pitch...``/``...Roll...`` (the airframe);
* camera: ``CalibratedFocalLength`` and ``CalibratedOpticalCenterX``/``Y`` (pixels of the full
  size photo), ``DewarpData`` (``date;fx,fy,cx,cy,k1,k2,p1,p2,k3``: cx, cy are offsets in pixels
  from the photo's centre, per DJI's Mavic 3M and Matrice 4 manuals) and ``DewarpFlag`` (1: the
  photo was already undistorted in the camera);
* mounting: ``CamReverse`` and ``GimbalReverse`` (1: mounted upside down, as on a top
  gimbal port; such a photo is refused: whether its pixels were turned back to match the
  gimbal's angles is not written);
* accuracy: ``RtkFlag`` (0 no position, 16 single point, 32-49 float, 50 fixed) and
  ``RtkStdLon``/``RtkStdLat``/``RtkStdHgt`` (one sigma, metres);
* time: ``UTCAtExposure`` (newer enterprise models).

EXIF (Pillow): make, model, orientation, ``FocalLength``, ``FocalLengthIn35mmFilm``, the
pixel size the camera wrote, ``DateTimeOriginal`` with ``SubSecTimeOriginal`` and
``OffsetTimeOriginal``, and GPS ``GPSDateStamp``/``GPSTimeStamp``.

**Intrinsics** (:func:`photo_intrinsics`), first that applies:

1. calibrated: ``DewarpData`` (fx, fy, centre + (cx, cy), distortion k1, k2, p1, p2, k3) where
   present, else ``CalibratedFocalLength`` with ``CalibratedOpticalCenterX/Y``. DJI states
   them for the full-size photo: the calibration's size is twice the designed optical centre
   (DJI puts it at the middle), else EXIF's pixel size; a photo resized since (same aspect
   within 1 %) scales them. DJI gives the centre as W/2, H/2 in a pixel-corner convention; in
   OpenCV's (pixel centres at integers) that is (W−1)/2, so half a pixel is taken off;
2. the model's sensor (:data:`DJI_SENSORS`, by EXIF model) with EXIF's focal length in mm:
   the photo spans the sensor's width when it is at least as wide as the sensor's aspect,
   else its height (a 4:3 photo from a 3:2 sensor is cropped at the sides);
3. EXIF's 35 mm equivalent focal length, through the diagonal:
   ``f_px = f35 · sqrt(W² + H²) / sqrt(36² + 24²)`` (good to a few per cent).

**Capture time** (:func:`capture_utc`), first that applies: ``UTCAtExposure``; EXIF's GPS date
and time stamps (UTC by definition); ``DateTimeOriginal`` (the drone's clock, set from the
remote controller's phone or tablet: **local time**) with the zone of ``OffsetTimeOriginal``,
or with ``utc_offset_h`` given by the user (which wins over ``OffsetTimeOriginal`` when both
are there, with a note). ``DateTimeOriginal`` is to the second unless ``SubSecTimeOriginal``
adds a fraction (EXIF's sub-second field is the part the whole seconds leave out: a clock
truncates). Without it the exposure lies anywhere in that second, so its middle is taken
(``+ 0.5 s``, as for a DJI SRT's whole seconds): the vessel is then placed to within its
speed times half a second, not a whole second behind on average.

**Gimbal yaw reference**: DJI's flight controller corrects its compass with the declination
at its GPS position, so ``GimbalYawDegree`` is taken as degrees from **true** north
(``yaw_reference="true"``); ``"magnetic"`` adds the World Magnetic Model's declination at the
photo's position and time, for an airframe known to report magnetic yaw.
"""

from __future__ import annotations

import io
import math
import re
import struct
import warnings
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import numpy as np

from harborsight.errors import InputError, brief
from harborsight.geometry.camera import CameraIntrinsics, sensor_focal_px
from harborsight.telemetry.accuracy import MAX_SIGMA_M, per_axis_from_class_m, per_axis_from_gst_m
from harborsight.telemetry.track import Track

DJI_NAMESPACE = "http://www.dji.com/drone-dji/1.0/"
#: file name suffixes read as photos
PHOTO_SUFFIXES = (".jpg", ".jpeg")
#: the largest file read (a DJI photo of 48 MP is about 25 MB)
MAX_PHOTO_BYTES = 200 * 1024 * 1024
YAW_REFERENCES = ("true", "magnetic")
ALTITUDES = ("relative", "absolute")


@dataclass(frozen=True)
class SensorFormat:
    width_mm: float
    height_mm: float
    name: str


_ONE_INCH = SensorFormat(13.2, 8.8, '1" CMOS, 13.2 x 8.8 mm')
_FOUR_THIRDS = SensorFormat(17.3, 13.0, '4/3" CMOS, 17.3 x 13.0 mm')
#: the 12 MP 1/2.3" sensors' 4:3 active area, 4000 x 3000 pixels of 1.55 um (the nominal
#: 6.17 x 4.55 mm is not 4:3, so a 4000 x 3000 photo "spanned its height" and fx read 2-4 %
#: long against the pitch and the EXIF 35 mm equivalent: distances 2-4 % short)
_ONE_OVER_2_3 = SensorFormat(6.20, 4.65, '1/2.3" CMOS, 4000 x 3000 at 1.55 um: 6.20 x 4.65 mm')
#: Sensor formats of DJI cameras by their EXIF model name, from DJI's published specifications
DJI_SENSORS = {
    "FC6310": _ONE_INCH,       # Phantom 4 Pro / Advanced
    "FC6310S": _ONE_INCH,      # Phantom 4 Pro V2.0
    "FC6310R": _ONE_INCH,      # Phantom 4 RTK
    "L1D-20C": _ONE_INCH,      # Mavic 2 Pro (Hasselblad L1D-20c)
    "FC3411": _ONE_INCH,       # Air 2S
    "L2D-20C": _FOUR_THIRDS,   # Mavic 3 (Hasselblad L2D-20c)
    "M3E": _FOUR_THIRDS,       # Mavic 3 Enterprise, wide camera
    "FC220": _ONE_OVER_2_3,    # Mavic Pro
    "FC330": _ONE_OVER_2_3,    # Phantom 4
}
#: RtkFlag codes and the GPS_CLASSES class each means (32-49 are float solutions)
RTK_FLAG_CLASSES = {16: "standalone", 50: "rtk", **{code: "dgps" for code in range(32, 50)}}
RTK_FLAG_NAMES = {0: "no position", 16: "single point", 50: "RTK fixed",
                  **{code: "RTK float" for code in range(32, 50)}}

_EXIF_IFD, _GPS_IFD = 0x8769, 0x8825
_ATTRIBUTE = re.compile(rb"([A-Za-z][\w.-]*):(\w+)\s*=\s*\"([^\"<>]{0,300})\"")
_ELEMENT = re.compile(rb"<([A-Za-z][\w.-]*):(\w+)>([^<>]{0,300})</\1:\2>")
_PREFIX = re.compile(rb"xmlns:([A-Za-z][\w.-]*)\s*=\s*\"http://www\.dji\.com/drone-dji/1\.0/?\"")


@dataclass
class DjiPhoto:
    """What one photo says; None where it does not say it."""

    source: Path
    width: int                               # decoded size, pixels
    height: int
    make: str | None = None
    model: str | None = None
    orientation: int | None = None
    xmp: dict[str, str] = field(default_factory=dict)    # drone-dji fields, as written
    exif: dict[str, object] = field(default_factory=dict)
    gps_exif: dict[int, object] = field(default_factory=dict)
    image_whole: bool = True
    notes: list[str] = field(default_factory=list)

    def number(self, *names: str) -> float | None:
        """The first of the XMP fields ``names`` that holds a finite number."""
        for name in names:
            value = _to_float(self.xmp.get(name))
            if value is not None:
                return value
        return None

    @property
    def position_deg(self) -> tuple[float, float] | None:
        lat = self.number("GpsLatitude")
        lon = self.number("GpsLongitude", "GpsLongtitude")
        if lat is not None and lon is not None and -90 <= lat <= 90 and -180 <= lon <= 180 \
                and (lat, lon) != (0.0, 0.0):
            return lat, lon
        return _exif_position(self.gps_exif)

    @property
    def gimbal_deg(self) -> tuple[float, float, float] | None:
        """Gimbal (camera) yaw, pitch, roll in degrees, when all three are given."""
        angles = [self.number(f"Gimbal{axis}Degree") for axis in ("Yaw", "Pitch", "Roll")]
        return None if None in angles else tuple(angles)

    @property
    def flight_deg(self) -> tuple[float, float, float] | None:
        angles = [self.number(f"Flight{axis}Degree") for axis in ("Yaw", "Pitch", "Roll")]
        return None if None in angles else tuple(angles)

    @property
    def rtk_flag(self) -> int | None:
        flag = self.number("RtkFlag")
        return None if flag is None else int(flag)

    def position_sigma_m(self) -> tuple[float | None, str]:
        """Per-axis horizontal sigma (m) the photo states, and where it comes from."""
        lon, lat = self.number("RtkStdLon"), self.number("RtkStdLat")
        flag = self.rtk_flag
        if flag == 0:
            return None, "RtkFlag 0 (no RTK position): sensor defaults"
        if lon is not None and lat is not None and 0 < lon <= MAX_SIGMA_M and 0 < lat <= MAX_SIGMA_M:
            value = per_axis_from_gst_m(lat, lon)
            if math.isfinite(value):
                return value, f"RtkStdLat/Lon {lat:g}/{lon:g} m"
        if flag is not None and flag in RTK_FLAG_CLASSES:
            value = float(per_axis_from_class_m([flag], [np.nan], RTK_FLAG_CLASSES)[0])
            return value, f"RtkFlag {flag} ({RTK_FLAG_NAMES[flag]}) class"
        return None, "none stated: sensor defaults"

    def summary(self) -> dict:
        """What an operator checks first (``telemetry show``)."""
        position = self.position_deg
        summary = {
            "source": str(self.source), "kind": "dji-photo",
            "make": self.make, "model": self.model,
            "drone_model": self.xmp.get("DroneModel") or self.xmp.get("ProductName"),
            "size": [self.width, self.height], "image_whole": self.image_whole,
            "lat_deg": None if position is None else position[0],
            "lon_deg": None if position is None else position[1],
            "relative_altitude_m": self.number("RelativeAltitude"),
            "absolute_altitude_m": self.number("AbsoluteAltitude"),
            "gimbal_ypr_deg": self.gimbal_deg, "flight_ypr_deg": self.flight_deg,
            "rtk_flag": self.rtk_flag,
            "rtk_std_m": [self.number(k) for k in ("RtkStdLon", "RtkStdLat", "RtkStdHgt")],
            "capture_local": self.exif.get("DateTimeOriginal"),
            "offset_time": self.exif.get("OffsetTimeOriginal"),
            "utc_at_exposure": self.xmp.get("UTCAtExposure"),
        }
        try:
            intrinsics, how = photo_intrinsics(self)
            summary["camera"] = _camera_block(intrinsics)
            summary["camera_from"] = how
        except InputError as exc:
            summary["camera"], summary["camera_from"] = None, exc.message
        try:
            when, how = capture_utc(self, None)
            summary["utc"], summary["clock"] = when.isoformat(), how
        except InputError as exc:
            summary["utc"], summary["clock"] = None, exc.message
        sigma, how = self.position_sigma_m()
        summary["position_sigma_m"], summary["accuracy"] = sigma, how
        summary["notes"] = list(self.notes)
        return summary


def read_dji_photo(path: str | Path) -> DjiPhoto:
    """Read a photo's XMP and EXIF. A file cut short or salted keeps what comes before the
    damage (its XMP fields are then read by pattern, with a note); :class:`InputError` naming
    the file when it is not a JPEG or holds no DJI field at all."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        if path.stat().st_size > MAX_PHOTO_BYTES:
            raise InputError(path, None, f"larger than {MAX_PHOTO_BYTES >> 20} MB: not a photo")
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"cannot read: {exc.strerror or exc}") from None
    if data[:3] != b"\xff\xd8\xff":
        raise InputError(path, None, "not a JPEG file (no Start Of Image marker)")
    from harborsight.images import incomplete_reason

    photo = DjiPhoto(source=path, width=0, height=0)
    if (reason := incomplete_reason(data)) is not None:
        photo.image_whole = False
        photo.notes.append(reason.replace("cannot decode image: ", "image data: "))
    packet = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(io.BytesIO(data)) as image:
                photo.width, photo.height = image.size
                packet = image.info.get("xmp")
                _read_exif(image.getexif(), photo)
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError, struct.error,
            KeyError, IndexError, TypeError, ZeroDivisionError) as exc:
        photo.notes.append(f"EXIF/JPEG header unreadable ({type(exc).__name__}): the XMP "
                           "fields found in the raw bytes are used")
    if isinstance(packet, str):
        packet = packet.encode("utf-8", "replace")
    fields = _xmp_fields(packet) if packet else None
    if fields is None:
        fields = _xmp_fields_by_pattern(data)
        if fields and packet:
            photo.notes.append("XMP packet not well-formed XML: its fields were read by pattern")
    photo.xmp = fields or {}
    if not photo.xmp and photo.make is None:
        raise InputError(path, "XMP", "no drone-dji XMP fields and no EXIF: not a DJI photo "
                         "(or its metadata was stripped)")
    if not photo.xmp:
        photo.notes.append("no drone-dji XMP fields: pose from EXIF alone (no gimbal attitude)")
    if photo.orientation not in (None, 1):
        photo.notes.append(f"EXIF Orientation {photo.orientation}: the photo was turned after "
                           "capture, so its pixels no longer match the camera")
    return photo


def _read_exif(exif, photo: DjiPhoto) -> None:
    base = dict(exif)
    photo.make = _text(base.get(271))
    photo.model = _text(base.get(272))
    orientation = base.get(274)
    photo.orientation = int(orientation) if isinstance(orientation, int) else None
    sub = exif.get_ifd(_EXIF_IFD)
    names = {36867: "DateTimeOriginal", 37521: "SubSecTimeOriginal",
             36881: "OffsetTimeOriginal", 37386: "FocalLength", 41989: "FocalLengthIn35mmFilm",
             40962: "PixelXDimension", 40963: "PixelYDimension", 41988: "DigitalZoomRatio"}
    for tag, name in names.items():
        if tag in sub:
            value = sub[tag]
            photo.exif[name] = _text(value) if isinstance(value, str | bytes) else value
    photo.gps_exif = dict(exif.get_ifd(_GPS_IFD))


def _text(value) -> str | None:
    if isinstance(value, bytes):
        value = value.decode("latin-1")
    if not isinstance(value, str):
        return None
    value = value.replace("\x00", "").strip()
    return value or None


def _to_float(value) -> float | None:
    """A number from an XMP or EXIF value (``"+12.50"``, a rational), None if not finite."""
    try:
        number = float(value.strip() if isinstance(value, str) else value)
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        return None
    return number if math.isfinite(number) else None


def _xmp_fields(packet: bytes) -> dict[str, str] | None:
    """drone-dji fields of a well-formed XMP packet (attributes and simple elements, whatever
    the prefix bound to DJI's namespace); None when it is not well-formed XML. A packet with
    a DTD (which XMP forbids) is not parsed as XML."""
    text = packet.strip(b"\x00 \r\n\t")
    if b"<!DOCTYPE" in text or b"<!ENTITY" in text:
        return None
    try:
        root = ElementTree.fromstring(text)
    except ElementTree.ParseError:
        return None
    fields: dict[str, str] = {}
    for element in root.iter():
        for key, value in element.attrib.items():
            if (name := _dji_name(key)) is not None:
                fields.setdefault(name, value.strip())
        if isinstance(element.tag, str) and element.text and (name := _dji_name(element.tag)):
            fields.setdefault(name, element.text.strip())
    return fields


def _dji_name(qualified: str) -> str | None:
    """``Name`` of an ElementTree name ``{namespace}Name`` in DJI's namespace (with or
    without its final slash), else None."""
    namespace, _, name = qualified[1:].partition("}") if qualified.startswith("{") else ("", "", "")
    return name if name and namespace.rstrip("/") == DJI_NAMESPACE.rstrip("/") else None


def _xmp_fields_by_pattern(data: bytes) -> dict[str, str]:
    """drone-dji fields found by pattern in raw bytes (a torn or malformed packet): every
    ``prefix:Name="value"`` and ``<prefix:Name>value</prefix:Name>`` whose prefix is bound to
    DJI's namespace (or is ``drone-dji``)."""
    start = data.find(b"<x:xmpmeta")
    if start < 0:
        start = data.find(b"drone-dji")
    if start < 0:
        return {}
    chunk = data[start:start + 256 * 1024]
    prefixes = {b"drone-dji", *(_PREFIX.findall(chunk))}
    fields: dict[str, str] = {}
    for pattern in (_ATTRIBUTE, _ELEMENT):
        for prefix, name, value in pattern.findall(chunk):
            if prefix in prefixes:
                fields.setdefault(name.decode("ascii"), value.decode("utf-8", "replace").strip())
    return fields


def _exif_position(gps: dict) -> tuple[float, float] | None:
    """Latitude, longitude from EXIF's GPS block (DMS rationals with N/S, E/W references)."""
    def degrees(dms, ref) -> float | None:
        try:
            d, m, s = (float(v) for v in dms)
        except (TypeError, ValueError, ZeroDivisionError):
            return None
        value = d + m / 60.0 + s / 3600.0
        sign = -1.0 if _text(ref) in ("S", "W") else 1.0
        return sign * value if math.isfinite(value) else None

    lat, lon = degrees(gps.get(2), gps.get(1)), degrees(gps.get(4), gps.get(3))
    if lat is None or lon is None or not (-90 <= lat <= 90 and -180 <= lon <= 180) \
            or (lat, lon) == (0.0, 0.0):
        return None
    return lat, lon


def photo_intrinsics(photo: DjiPhoto) -> tuple[CameraIntrinsics, str]:
    """The photo's intrinsics at its decoded size and how they were found (module
    docstring); :class:`InputError` naming the field when nothing gives them."""
    width, height = photo.width, photo.height
    if width <= 0 or height <= 0:
        raise InputError(photo.source, "size", "the image size is unknown (JPEG header unreadable)")
    focal = photo.number("CalibratedFocalLength")
    dewarp = _dewarp(photo)
    centre_x, centre_y = photo.number("CalibratedOpticalCenterX"), photo.number("CalibratedOpticalCenterY")
    if focal is not None or dewarp is not None:
        native = _calibration_size(photo, centre_x, centre_y)
        scale = width / native[0]
        if abs(height / native[1] - scale) > 0.01 * scale:
            raise InputError(photo.source, "CalibratedOpticalCenterX", f"calibrated for "
                             f"{native[0]:g}x{native[1]:g}, the photo is {width}x{height}: "
                             "not the same aspect (cropped?)")
        half_w, half_h = native[0] / 2.0, native[1] / 2.0
        already_undistorted = photo.number("DewarpFlag") == 1
        if dewarp is not None:
            fx, fy, dx, dy, *coefficients = dewarp
            distortion = (0.0,) * 5 if already_undistorted else tuple(coefficients)
            how = "DewarpData (DJI calibration)"
        else:
            fx = fy = focal
            dx = 0.0 if centre_x is None else centre_x - half_w
            dy = 0.0 if centre_y is None else centre_y - half_h
            distortion, how = (0.0,) * 5, "CalibratedFocalLength (DJI's design values, no distortion)"
            if photo.xmp.get("DewarpDataK6"):
                how += ("; DewarpDataK6 (a six-coefficient lens model, Matrice 4) is not read: "
                        "give --camera for the lens's distortion")
        intrinsics = CameraIntrinsics(
            width, height, fx * scale, fy * scale,
            (half_w + dx) * scale - 0.5, (half_h + dy) * scale - 0.5, distortion)
        if already_undistorted:
            how += ", the photo undistorted in the camera (DewarpFlag 1)"
        if scale != 1.0:
            how += f", scaled by {scale:.4g} to the photo's size"
        return _checked(photo, intrinsics, how)
    focal_mm = _to_float(photo.exif.get("FocalLength"))
    sensor = DJI_SENSORS.get((photo.model or "").upper())
    if sensor is not None and focal_mm is not None and focal_mm > 0:
        f_px, spans = sensor_focal_px(focal_mm, sensor.width_mm, sensor.height_mm, width, height)
        return _checked(photo, CameraIntrinsics(width, height, f_px, f_px, (width - 1) / 2.0,
                                                (height - 1) / 2.0),
                        f"{photo.model}: {sensor.name}, EXIF focal length {focal_mm:g} mm "
                        f"(the photo spans the sensor's {spans})")
    f35 = _to_float(photo.exif.get("FocalLengthIn35mmFilm"))
    if f35 is not None and f35 > 0:
        # the equivalent is the whole sensor's: a photo wider than 4:3 (16:9) is a crop of
        # what DJI's small drones carry, a 4:3 sensor, spanning its width, whose diagonal is
        # 5/4 of it (the photo's own diagonal read 8.9 % short); a 4:3 or 3:2 photo is the
        # whole sensor
        cropped = width / height > 1.6       # wider than 3:2: a 16:9 (or wider) crop
        diagonal_px = 1.25 * width if cropped else math.hypot(width, height)
        f_px = f35 * diagonal_px / math.hypot(36.0, 24.0)
        return _checked(photo, CameraIntrinsics(width, height, f_px, f_px, (width - 1) / 2.0,
                                                (height - 1) / 2.0),
                        f"EXIF 35 mm equivalent focal length {f35:g} mm (through the "
                        + ("diagonal of a 4:3 sensor the photo crops" if cropped else "diagonal")
                        + ": good to a few per cent; give --camera for better)")
    raise InputError(photo.source, "CalibratedFocalLength", "no calibrated focal length, no "
                     "known camera model with a focal length, no 35 mm equivalent: give --camera")


def _dewarp(photo: DjiPhoto) -> list[float] | None:
    text = photo.xmp.get("DewarpData")
    if not text:
        return None
    numbers = [_to_float(v) for v in text.split(";")[-1].split(",")]
    if len(numbers) < 9 or None in numbers[:9] or not (numbers[0] > 0 and numbers[1] > 0):
        photo.notes.append(f"DewarpData {brief(text, 60)} is not fx,fy,cx,cy,k1,k2,p1,p2,k3: "
                           "ignored")
        return None
    return numbers[:9]


def _calibration_size(photo: DjiPhoto, centre_x: float | None, centre_y: float | None
                      ) -> tuple[float, float]:
    """The size the calibration is stated for: twice DJI's designed optical centre, else the
    pixel size EXIF states, else the decoded size."""
    if centre_x and centre_y and centre_x > 0 and centre_y > 0:
        return 2.0 * centre_x, 2.0 * centre_y
    exif_w = _to_float(photo.exif.get("PixelXDimension"))
    exif_h = _to_float(photo.exif.get("PixelYDimension"))
    if exif_w and exif_h and exif_w > 0 and exif_h > 0:
        return exif_w, exif_h
    return float(photo.width), float(photo.height)


def _checked(photo: DjiPhoto, intrinsics: CameraIntrinsics, how: str) -> tuple[CameraIntrinsics, str]:
    values = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy, *intrinsics.distortion)
    if not all(math.isfinite(v) for v in values) or not (0 < intrinsics.fx < 1e6 and 0 < intrinsics.fy < 1e6):
        raise InputError(photo.source, "CalibratedFocalLength", f"intrinsics from {how} are not "
                         "usable (a focal length of zero, negative or beyond reason)")
    return intrinsics, how


_EXIF_TIME = re.compile(r"^\s*(\d{4})[:-](\d{2})[:-](\d{2})[ T](\d{2}):(\d{2}):(\d{2})(?:[.,](\d{1,9}))?")
_OFFSET = re.compile(r"^\s*([+-])(\d{2}):?(\d{2})\s*$")


def _exif_time(text, fraction=None) -> datetime | None:
    match = _EXIF_TIME.match(text) if isinstance(text, str) else None
    if match is None:
        return None
    digits = match.group(7) or (str(fraction).strip() if fraction is not None else "")
    digits = digits if digits.isdigit() else ""
    try:
        when = datetime(*(int(g) for g in match.groups()[:6]))
    except ValueError:
        return None
    return when + timedelta(seconds=float("0." + digits)) if digits else when


def _has_fraction(text) -> bool:
    """Whether an EXIF time carries its own fraction of a second (``...:05.25``)."""
    match = _EXIF_TIME.match(text) if isinstance(text, str) else None
    return bool(match and match.group(7))


def capture_utc(photo: DjiPhoto, utc_offset_h: float | None) -> tuple[datetime, str]:
    """The photo's capture time in UTC and which clock gave it (module docstring);
    :class:`InputError` naming the field when it cannot be placed in UTC."""
    exposure = photo.xmp.get("UTCAtExposure")
    if exposure:
        when = _exif_time(exposure)
        if when is not None:
            return when.replace(tzinfo=UTC), "XMP UTCAtExposure (UTC)"
        photo.notes.append(f"UTCAtExposure {brief(exposure)} is not a time: ignored")
    gps = photo.gps_exif
    if gps.get(29) and gps.get(7):
        try:
            h, m, s = (float(v) for v in gps[7])
            day = datetime.strptime(_text(gps[29]) or "", "%Y:%m:%d")
            if all(map(math.isfinite, (h, m, s))):
                return (day.replace(tzinfo=UTC) + timedelta(hours=h, minutes=m, seconds=s),
                        "EXIF GPSDateStamp/GPSTimeStamp (UTC)")
        except (TypeError, ValueError, ZeroDivisionError, OverflowError):
            photo.notes.append("EXIF GPS date/time stamp unreadable: ignored")
    local = _exif_time(photo.exif.get("DateTimeOriginal"), photo.exif.get("SubSecTimeOriginal"))
    if local is None:
        raise InputError(photo.source, "DateTimeOriginal", "no capture time (no UTCAtExposure, "
                         "no GPS time stamp, no readable EXIF DateTimeOriginal)")
    if not photo.exif.get("SubSecTimeOriginal") and not _has_fraction(photo.exif.get("DateTimeOriginal")):
        local += timedelta(seconds=0.5)     # the middle of the second a truncated clock shows
        resolution = ", to the second (its middle taken)"
    else:
        resolution = ""
    offset = _OFFSET.match(str(photo.exif.get("OffsetTimeOriginal") or ""))
    if utc_offset_h is not None:
        if offset is not None:
            photo.notes.append(f"OffsetTimeOriginal {photo.exif['OffsetTimeOriginal']} "
                               f"overridden by the given UTC offset {utc_offset_h:+g} h")
        zone = timezone(timedelta(hours=utc_offset_h))
        how = f"EXIF DateTimeOriginal, local time at UTC{utc_offset_h:+g} h (given){resolution}"
    elif offset is not None:
        sign = -1 if offset.group(1) == "-" else 1
        zone = timezone(sign * timedelta(hours=int(offset.group(2)), minutes=int(offset.group(3))))
        how = f"EXIF DateTimeOriginal with OffsetTimeOriginal {offset.group(0).strip()}{resolution}"
    else:
        raise InputError(photo.source, "DateTimeOriginal", f"{local.isoformat()} is the drone's "
                         "local time with no zone: give its UTC offset (--utc-offset-h)")
    try:
        return local.replace(tzinfo=zone).astimezone(UTC), how
    except OverflowError:
        raise InputError(photo.source, "DateTimeOriginal", "outside the years 1-9999 in UTC"
                         ) from None


def photo_track(photo: DjiPhoto, *, altitude: str = "relative", yaw_reference: str = "true",
                when: datetime | None = None) -> Track:
    """The photo as a one-sample drone :class:`Track` (gimbal attitude, the photo's stated
    accuracy) at ``t_s = 0``, ``utc_start`` the capture time; what
    :func:`~harborsight.telemetry.metadata.frames_at_times` samples."""
    if altitude not in ALTITUDES:
        raise ValueError(f"altitude {altitude!r}: expected one of {', '.join(ALTITUDES)}")
    if yaw_reference not in YAW_REFERENCES:
        raise ValueError(f"yaw reference {yaw_reference!r}: expected one of "
                         f"{', '.join(YAW_REFERENCES)}")
    position = photo.position_deg
    if position is None:
        raise InputError(photo.source, "GpsLatitude", "no position (XMP GpsLatitude/GpsLongitude "
                         "or EXIF GPS)")
    field_name = "RelativeAltitude" if altitude == "relative" else "AbsoluteAltitude"
    alt_m = photo.number(field_name)
    if alt_m is None:
        raise InputError(photo.source, field_name, "missing: no altitude of this kind (try the "
                         "other --altitude)")
    gimbal = photo.gimbal_deg
    if gimbal is None:
        raise InputError(photo.source, "GimbalYawDegree", "no gimbal attitude (GimbalYawDegree, "
                         "GimbalPitchDegree, GimbalRollDegree)")
    yaw, pitch, roll = gimbal
    notes = list(photo.notes)
    if yaw_reference == "magnetic":
        from harborsight.telemetry.declination import magnetic_declination_deg

        if when is None:
            raise InputError(photo.source, "DateTimeOriginal", "a magnetic yaw needs the capture "
                             "time for the declination")
        try:
            declination = magnetic_declination_deg(*position, when)
        except ValueError as exc:
            raise InputError(photo.source, "DateTimeOriginal", str(exc)) from None
        yaw += declination
        notes.append(f"gimbal yaw taken as magnetic: declination {declination:+.2f}° added")
    sigma, how = photo.position_sigma_m()
    alt_sigma = photo.number("RtkStdHgt") if altitude == "absolute" else None
    if alt_sigma is not None and not 0 < alt_sigma <= MAX_SIGMA_M:
        alt_sigma = None
    notes.append(f"position accuracy: {how}")
    # AltitudeType (DJI's enterprise XMP): "RtkAlt" is the RTK receiver's ellipsoid height,
    # tens of metres from mean sea level where the geoid is far from the ellipsoid
    altitude_type = photo.xmp.get("AltitudeType")
    altitude_type = altitude_type.strip() if isinstance(altitude_type, str) else None
    if altitude == "relative":
        reference = "barometric height above the take-off point (RelativeAltitude)"
    elif altitude_type == "RtkAlt":
        reference = ("DJI AbsoluteAltitude, AltitudeType RtkAlt: the RTK receiver's ellipsoid "
                     "height (WGS 84, or the RTK service's frame), not mean sea level")
    else:
        reference = ("DJI AbsoluteAltitude (mean sea level on most models, ellipsoid on RTK ones"
                     + (f"; AltitudeType {altitude_type}" if altitude_type else "") + ")")
    # EXIF DigitalZoomRatio (0: none used): a centre crop, enlarged, so the intrinsics scale
    # with it (metadata.digitally_zoomed), as for a video's SRT
    zoom = _to_float(photo.exif.get("DigitalZoomRatio"))
    zoom = zoom if zoom is not None and math.isfinite(zoom) and zoom > 0 else None
    if zoom is not None and abs(zoom - 1.0) > 1e-3:
        notes.append(f"digital zoom {zoom:g}x (EXIF DigitalZoomRatio): a centre crop of the "
                     "sensor, so the intrinsics are scaled by it about the image centre")
    return Track(
        source=photo.source, kind="dji-photo", t_s=[0.0],
        lat_deg=[position[0]], lon_deg=[position[1]], alt_m=[alt_m], alt_reference=reference,
        digital_zoom=None if zoom is None else [zoom],
        yaw_deg=[yaw], pitch_deg=[pitch], roll_deg=[roll], attitude_of="gimbal",
        position_sigma_m=None if sigma is None else [sigma],
        alt_sigma_m=None if alt_sigma is None else [alt_sigma],
        utc_start=when, clock="the photo's capture time", notes=notes)


def _camera_block(intrinsics: CameraIntrinsics) -> dict:
    return {"width": intrinsics.width, "height": intrinsics.height,
            "fx": round(intrinsics.fx, 4), "fy": round(intrinsics.fy, 4),
            "cx": round(intrinsics.cx, 4), "cy": round(intrinsics.cy, 4),
            "distortion": [float(v) for v in intrinsics.distortion] or [0.0] * 5}


@dataclass
class PhotoFrame:
    frame: dict | None          # harborsight.frame/1, or None when the photo is left out
    reason: str | None          # why it was left out
    notes: list[str]


def photo_frame(
    photo: DjiPhoto, vessel: Track, *, image: str, water_level_m: float,
    utc_offset_h: float | None = None, altitude: str = "relative", yaw_reference: str = "true",
    vessel_offset_s: float = 0.0, max_gap_s: float = 1.0, camera: dict | None = None,
    index: int = 0,
) -> PhotoFrame:
    """One ``harborsight.frame/1`` for the photo, the vessel sampled at its capture time (plus
    ``vessel_offset_s``). ``image`` is the value of the frame's ``image`` key (the photo's path
    as seen from the frame file); ``camera`` a frame/1 camera block that replaces the photo's
    own intrinsics. :class:`InputError` for a photo that cannot be a frame."""
    from harborsight.telemetry.metadata import frames_at_times

    if not photo.image_whole:
        raise InputError(photo.source, "image", photo.notes[0] if photo.notes else "cut short")
    if photo.orientation not in (None, 1):
        # decoders turn such a photo (OpenCV does): its pixels would no longer be the camera's
        raise InputError(photo.source, "Orientation", f"EXIF Orientation {photo.orientation}: "
                         "the photo was turned after capture, and a decoder turns it back, so "
                         "its pixels are not the camera's; save it with Orientation 1")
    for flag in ("CamReverse", "GimbalReverse"):
        text = str(photo.xmp.get(flag, "")).strip().lower()
        if photo.number(flag) not in (None, 0.0) or text == "true":
            # a camera or gimbal mounted upside down (a top gimbal port): DJI writes the
            # gimbal's angles, and whether the photo was turned back to match them is not said
            raise InputError(photo.source, flag, f"{brief(photo.xmp.get(flag))}: the camera is "
                             "mounted upside down, and the photo does not say whether its pixels "
                             "were turned back to match the gimbal's angles; a camera that looks "
                             "down at a vessel hangs under the drone (write the frame/1 file by "
                             "hand if this one does)")
    when, clock = capture_utc(photo, utc_offset_h)
    drone = photo_track(photo, altitude=altitude, yaw_reference=yaw_reference, when=when)
    if camera is None:
        intrinsics, how = photo_intrinsics(photo)
        camera = _camera_block(intrinsics)
    else:
        how = "given (--camera)"
        if (camera["width"], camera["height"]) != (photo.width, photo.height):
            raise InputError(photo.source, "size", f"the camera is calibrated for "
                             f"{camera['width']}x{camera['height']}, the photo is "
                             f"{photo.width}x{photo.height}")
        if photo.number("DewarpFlag") == 1 and any(camera.get("distortion") or ()):
            # the camera undistorted the photo already: the lens model would be applied twice
            # (a P4 RTK's k1 -0.26 put a point 40 m from the nadir at 45.6 m, 60 m up)
            camera = {**camera, "distortion": [0.0] * len(camera["distortion"])}
            how += ("; its lens distortion left out: the photo was undistorted in the camera "
                    "(DewarpFlag 1)")
    if vessel.utc_start is None:
        raise InputError(vessel.source, "time", "the vessel track states no UTC time")
    vessel_t = np.array([vessel.seconds_of(when) + vessel_offset_s])
    result = frames_at_times(drone, vessel, camera, np.zeros(1), vessel_t, [when],
                             water_level_m=water_level_m, max_gap_s=max_gap_s, indices=[index])
    notes = [*drone.notes, f"clock: {clock}", f"camera: {how}"]
    if not result.frames:
        return PhotoFrame(None, result.skipped[0][1], notes)
    frame = {"schema": result.frames[0]["schema"], "image": image, **result.frames[0]}
    frame["telemetry"].update({"photo_clock": clock, "camera_from": how})
    return PhotoFrame(frame, None, notes)
