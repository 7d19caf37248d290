"""DJI-style still photos for tests, written by the tools' own writers: the XMP packet by
ElementTree (DJI's ``drone-dji`` namespace and field names, as DJI's manuals list them), the
JPEG and its EXIF by Pillow. Never a hand-typed byte stream."""

from __future__ import annotations

import io
import xml.etree.ElementTree as ElementTree
from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image

DJI = "http://www.dji.com/drone-dji/1.0/"
RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
XMP_META = "adobe:ns:meta/"


def xmp_packet(fields: dict[str, str], *, as_elements: tuple[str, ...] = (),
               prefix: str = "drone-dji") -> bytes:
    """An XMP packet with ``fields`` in DJI's namespace, as attributes of one
    ``rdf:Description`` (as DJI writes them) or, for the names in ``as_elements``, as child
    elements; ``prefix`` is the prefix bound to DJI's namespace."""
    ElementTree.register_namespace("x", XMP_META)
    ElementTree.register_namespace("rdf", RDF)
    ElementTree.register_namespace(prefix, DJI)
    meta = ElementTree.Element(f"{{{XMP_META}}}xmpmeta")
    rdf = ElementTree.SubElement(meta, f"{{{RDF}}}RDF")
    description = ElementTree.SubElement(rdf, f"{{{RDF}}}Description",
                                         {f"{{{RDF}}}about": "DJI Meta Data"})
    for name, value in fields.items():
        if name in as_elements:
            ElementTree.SubElement(description, f"{{{DJI}}}{name}").text = value
        else:
            description.set(f"{{{DJI}}}{name}", value)
    body = ElementTree.tostring(meta, encoding="utf-8", xml_declaration=False)
    return (b'<?xpacket begin="\xef\xbb\xbf" id="W5M0MpCehiHzreSzNTczkc9d"?>' + body
            + b'<?xpacket end="w"?>')


def _dms(value: float) -> tuple[Fraction, Fraction, Fraction]:
    value = abs(value)
    degrees = int(value)
    minutes = int((value - degrees) * 60)
    seconds = (value - degrees - minutes / 60) * 3600
    return Fraction(degrees), Fraction(minutes), Fraction(round(seconds * 10000), 10000)


def write_dji_photo(path: Path, rgb: np.ndarray, xmp: dict[str, str] | None, *,
                    make: str = "DJI", model: str | None = "FC6310R",
                    exif: dict[str, object] | None = None,
                    gps: tuple[float, float] | None = None,
                    gps_time: tuple[str, tuple[float, float, float]] | None = None,
                    as_elements: tuple[str, ...] = (), prefix: str = "drone-dji",
                    quality: int = 92) -> Path:
    """A JPEG of ``rgb`` with DJI's XMP fields ``xmp`` and EXIF: make, model, the named Exif
    IFD fields of ``exif`` (``DateTimeOriginal``, ``SubSecTimeOriginal``,
    ``OffsetTimeOriginal``, ``FocalLength``, ``FocalLengthIn35mmFilm``, ``PixelXDimension``,
    ``PixelYDimension``, ``DigitalZoomRatio``), ``gps`` (lat, lon) and ``gps_time`` (date
    "YYYY:MM:DD", h, m, s)."""
    tags = {"DateTimeOriginal": 36867, "SubSecTimeOriginal": 37521, "OffsetTimeOriginal": 36881,
            "FocalLength": 37386, "FocalLengthIn35mmFilm": 41989, "PixelXDimension": 40962,
            "PixelYDimension": 40963, "DigitalZoomRatio": 41988}
    info = Image.Exif()
    info[271] = make
    if model:
        info[272] = model
    sub = info.get_ifd(0x8769)
    for name, value in (exif or {}).items():
        sub[tags[name]] = value
    if gps is not None or gps_time is not None:
        block = info.get_ifd(0x8825)
        if gps is not None:
            block[1], block[2] = ("N" if gps[0] >= 0 else "S"), _dms(gps[0])
            block[3], block[4] = ("E" if gps[1] >= 0 else "W"), _dms(gps[1])
        if gps_time is not None:
            block[29] = gps_time[0]
            block[7] = tuple(Fraction(v).limit_denominator(1000) for v in gps_time[1])
    buffer = io.BytesIO()
    options = {"exif": info, "quality": quality}
    if xmp is not None:
        options["xmp"] = xmp_packet(xmp, as_elements=as_elements, prefix=prefix)
    Image.fromarray(np.ascontiguousarray(rgb)).save(buffer, "JPEG", **options)
    path.write_bytes(buffer.getvalue())
    return path


#: DJI's field values of a real Phantom 4 RTK photo (5472x3648) as published in a forum post
#: about importing DJI calibrations (the DewarpData, calibrated values and RTK figures);
#: position and attitude are replaced by each test
P4RTK_CALIBRATION = {
    "CalibratedFocalLength": "3666.666504",
    "CalibratedOpticalCenterX": "2736.000000",
    "CalibratedOpticalCenterY": "1824.000000",
    "DewarpData": "2018-09-06;3684.480000000000,3677.570000000000,2.240000000000,"
                  "22.050000000000,-0.263482000000,0.106788000000,0.000037110700,"
                  "-0.000327247000,-0.030078300000",
    "DewarpFlag": "0",
}
