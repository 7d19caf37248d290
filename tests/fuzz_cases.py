"""Generated inputs for every parser and for ``measure_frame`` (issue #30), shared by the
property tests (``tests/test_fuzz_parsers.py``, a few dozen cases each) and the benchmark
(``benchmarks/fuzz_parsers.py``, 10,000 each).

Each entry of :data:`TARGETS` is ``(strategy, run)``: ``run(case)`` feeds one drawn case to
the parser and returns ``"ok"`` or ``"refused"`` (a :class:`HarborsightError`); anything else
it raises is a crash. On ``"ok"`` it also checks what came back (finite numbers, strict
JSON, no negative distance in an ``ok`` section) and raises ``AssertionError`` if not.
Text inputs are the bundled samples (and the real logs in ``../shared/data/telemetry``
where they are there) torn, cut and salted with the values that broke parsers before:
numbers of 400 and 5000 digits, NaN, infinities, nesting 100,000 deep, Latin-1 bytes,
dates out of the calendar.
"""

from __future__ import annotations

import copy
import functools
import json
import math
import shutil
import tempfile
from datetime import datetime
from importlib import resources
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from harborsight.errors import HarborsightError

SAMPLES = Path(str(resources.files("harborsight") / "data" / "samples"))
SHARED_LOGS = Path(__file__).resolve().parents[2] / "shared" / "data" / "telemetry"
LOGS = SAMPLES / "flight" / "logs"

#: text that broke, or could break, a parser: put in place of a span of a sample
TOKENS = [
    "", "0", "-0", "-1", "1e308", "1.0e+308", "-1.0e+308", "1e-308", "2e9", "4294967296",
    "nan", "NaN", ".nan", "inf", "-inf", "Infinity", "-Infinity", ".inf", "1" + "0" * 400,
    "9" * 20, "1" + "0" * 4999, "-" + "9" * 5000, "[" * 100_000, "{" * 3000, "\x00", "\xe9",
    '"', "'", "[", "]", "{", "}", ":", ",", ", ", "\n", "\r\n", "\t", " ", "null", "true",
    "[]", "{}", "\u00f8", "\U0001f4a5", "%", "*", "$", "<", ">", "</data>", "&", "!!opencv-matrix",
    "--", "-->", "- ", "2024-13-01", "9999-12-31 23:59:59", "0001-01-01 00:00:00",
    "00:00:00,000 --> 99:99:99,999", "[altitude: 11.0", "GPS(", "\ufeff",
]
token = st.one_of(st.sampled_from(TOKENS), st.text(max_size=6))


@st.composite
def mutated_text(draw, seeds: list[str]) -> str:
    """A seed text with up to four spans replaced, deleted, repeated or cut."""
    text = draw(st.sampled_from(seeds))
    for _ in range(draw(st.integers(0, 4))):
        kind = draw(st.sampled_from(["replace", "insert", "delete", "cut", "repeat", "line"]))
        at = int(draw(st.floats(0.0, 1.0)) * len(text))
        span = draw(st.integers(0, 40))
        if kind == "replace":
            text = text[:at] + draw(token) + text[at + span:]
        elif kind == "insert":
            text = text[:at] + draw(token) + text[at:]
        elif kind == "delete":
            text = text[:at] + text[at + span:]
        elif kind == "cut":
            text = text[:at]
        elif kind == "repeat":
            text = text[:at + span] + text[at:]
        else:                   # one line's value replaced, keeping what precedes it
            lines = text.split("\n")
            k = min(int(at / max(len(text), 1) * len(lines)), len(lines) - 1)
            head, sep, _ = lines[k].partition(draw(st.sampled_from([":", ",", " "])))
            lines[k] = head + sep + draw(token)
            text = "\n".join(lines)
    return text


@st.composite
def text_bytes(draw, seeds: list[str], encoding: str = "utf-8") -> bytes:
    """:func:`mutated_text` encoded, now and then with a Latin-1 byte or a byte order mark."""
    data = draw(mutated_text(seeds)).encode(encoding, errors="surrogatepass")
    if draw(st.integers(0, 9)) == 0:
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.sampled_from([b"\xe9", b"\xff\xfe", b"\xef\xbb\xbf", b"\x80"])) + data[at:]
    return data


@st.composite
def mutated_bytes(draw, seed: bytes) -> bytes:
    """A binary log with up to six bytes flipped, spans zeroed, repeated or cut."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["flip", "zero", "cut", "repeat", "insert", "flip"]))
        at = int(draw(st.floats(0.0, 1.0)) * len(data))
        span = draw(st.integers(1, 64))
        if kind == "flip" and data:
            data[min(at, len(data) - 1)] ^= draw(st.integers(1, 255))
        elif kind == "zero":
            data[at:at + span] = bytes(len(data[at:at + span]))
        elif kind == "cut":
            del data[at:]
        elif kind == "repeat":
            data[at:at] = data[at:at + span]
        else:
            data[at:at] = draw(st.binary(min_size=1, max_size=span))
    return bytes(data)


# -- values for structured documents ----------------------------------------------------------

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**6, 10**6),
    st.sampled_from([0, -0.0, 1e-300, 1e300, 1.7e308, 10**400, -10**400, 2**63, 1e30, 5000,
                     1000.0, 1000.0000001, 0.1, 0.099]),
    st.floats(-200.0, 200.0))
leaves = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8),
                   st.sampled_from(["waterline", "silhouette", "bow", "port", "up", "1e3", "nan"]))
json_values = st.recursive(leaves, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=6), inner, max_size=4),
                           max_leaves=10)


def _paths(node, prefix=()) -> list[tuple]:
    """Every key path of a JSON-like tree (lists by position)."""
    found = [prefix] if prefix else []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        found += _paths(value, (*prefix, key))
    return found


@st.composite
def edited_document(draw, base: dict) -> dict:
    """``base`` with up to five values replaced, removed or added at random places."""
    doc = copy.deepcopy(base)
    paths = _paths(doc)
    for _ in range(draw(st.integers(1, 5))):
        path = draw(st.sampled_from(paths))
        node = doc
        try:
            for key in path[:-1]:
                node = node[key]
            kind = draw(st.sampled_from(["set", "set", "set", "delete", "add"]))
            if kind == "set":
                node[path[-1]] = draw(json_values)
            elif kind == "delete" and isinstance(node, dict):
                node.pop(path[-1], None)
            elif isinstance(node, dict):
                node[draw(st.text(max_size=6))] = draw(json_values)
        except (KeyError, IndexError, TypeError):    # an earlier edit moved the tree
            continue
    return doc


# -- scratch files ----------------------------------------------------------------------------

@functools.cache
def scratch() -> Path:
    """A folder for the files of the cases (with the harbour tug's hull mesh)."""
    folder = Path(tempfile.mkdtemp(prefix="harborsight-fuzz-"))
    shutil.copy(SAMPLES / "vessels" / "harbour-tug" / "hull.stl", folder / "hull.stl")
    return folder


def write_case(name: str, data: bytes | str) -> Path:
    path = scratch() / name
    path.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8", "surrogatepass"))
    return path


def _refused(call) -> str:
    try:
        call()
    except HarborsightError:
        return "refused"
    return "ok"


def _finite(*arrays) -> bool:
    return all(np.all(np.isfinite(np.asarray(a, dtype=float))) for a in arrays if a is not None)


# -- frame JSON -------------------------------------------------------------------------------

FRAME = json.loads((SAMPLES / "frames" / "000000.json").read_text())
FRAME.pop("ground_truth")
FRAME.pop("simulation")
FRAME_TEXT = json.dumps(FRAME, indent=1)


def _check_frame(meta) -> None:
    from harborsight.frame import FrameGeometry

    cam = meta.camera
    assert _finite([meta.uav_lat_deg, meta.uav_lon_deg, meta.uav_alt_m, meta.yaw_deg,
                    meta.pitch_deg, meta.roll_deg, meta.vessel_lat_deg, meta.vessel_lon_deg,
                    meta.vessel_heading_deg, meta.water_level_m, cam.fx, cam.fy, cam.cx, cam.cy,
                    *cam.distortion])
    assert cam.width >= 1 and cam.height >= 1 and meta.height_above_water_m > 0
    FrameGeometry.from_metadata(meta)     # the next step of every command; may refuse


def run_frame_dict(doc: dict) -> str:
    from harborsight.frame import parse_frame_metadata

    return _refused(lambda: _check_frame(parse_frame_metadata(doc, "fuzz.json",
                                                              base_dir=scratch())))


def run_frame_file(data: bytes) -> str:
    from harborsight.frame import load_frame_metadata

    path = write_case("frame.json", data)
    return _refused(lambda: _check_frame(load_frame_metadata(path)))


# -- JSON lines -------------------------------------------------------------------------------

_LINE = {k: v for k, v in FRAME.items() if k not in ("image", "vessel_spec")}
JSONL_TEXT = "\n".join(json.dumps({**_LINE, "timestamp": f"2026-05-01T12:00:0{i}Z"})
                       for i in range(3)) + "\n"
JSONL_INDEXED = "\n".join(json.dumps({**_LINE, "frame_index": i}) for i in (0, 2, 5)) + "\n"


def run_json_lines(data: bytes) -> str:
    from harborsight.flight.sources import FrameMetadata, read_metadata_lines

    path = write_case("flight.jsonl", data)

    def read() -> None:
        by_frame, orphans, line_of, time_errors = read_metadata_lines(path, "flight")
        for index, entry in by_frame.items():
            assert isinstance(index, int) and index >= 0 and index in line_of
            assert isinstance(entry, FrameMetadata | str)
            if isinstance(entry, str):
                assert "\n" not in entry and len(entry) < 2000, entry
        assert all(isinstance(o, str) and "\n" not in o for o in orphans)
        assert set(time_errors) <= set(by_frame)

    return _refused(read)


# -- vessel.yaml ------------------------------------------------------------------------------

VESSEL_TEXT = (SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml").read_text()
VESSEL_DIMENSIONS = {"name": "box", "dimensions": {"to_bow": 30.0, "to_stern": 10.0,
                                                   "to_port": 5.0, "to_starboard": 5.0},
                     "air_draft_m": 8.0, "sections": 16}
VESSEL_MESH = {"name": "tug", "hull_mesh": "hull.stl", "mesh_axes": ["bow", "port", "up"],
               "gps_antenna": [20.0, 0.0, 9.0], "waterline_m": 0.0, "outline": "waterline",
               "section_length_m": 4.0}


def _check_vessel(spec) -> None:
    from harborsight.vessel.spec import MAX_VESSEL_SIZE_M

    assert _finite(spec.outline, spec.hull_points)
    assert 0 < spec.length_m <= MAX_VESSEL_SIZE_M and 0 < spec.beam_m <= MAX_VESSEL_SIZE_M
    sections = spec.sections()
    assert 1 <= sections.n_sections <= 1000


def run_vessel_doc(doc: dict) -> str:
    from harborsight.vessel.spec import parse_vessel_spec

    return _refused(lambda: _check_vessel(parse_vessel_spec(doc, scratch() / "vessel.yaml")))


def run_vessel_file(data: bytes) -> str:
    from harborsight.vessel.spec import load_vessel_spec

    path = write_case("vessel.yaml", data)
    return _refused(lambda: _check_vessel(load_vessel_spec(path)))


# -- camera calibration -----------------------------------------------------------------------

OPENCV_YAML = """%YAML:1.0
---
image_width: 640
image_height: 360
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 454.66, 0., 319.5, 0., 454.66, 179.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 1
   cols: 5
   dt: d
   data: [ -0.26, 0.08, 0., 0., 0. ]
"""
OPENCV_XML = """<?xml version="1.0"?>
<opencv_storage>
<image_width>640</image_width>
<image_height>360</image_height>
<camera_matrix type_id="opencv-matrix">
  <rows>3</rows>
  <cols>3</cols>
  <dt>d</dt>
  <data>454.66 0. 319.5 0. 454.66 179.5 0. 0. 1.</data></camera_matrix>
<distortion_coefficients type_id="opencv-matrix">
  <rows>5</rows>
  <cols>1</cols>
  <dt>d</dt>
  <data>-0.26 0.08 0. 0. 0.</data></distortion_coefficients>
</opencv_storage>
"""
ROS_YAML = """image_width: 640
image_height: 360
camera_name: fuzz
camera_matrix:
  rows: 3
  cols: 3
  data: [454.66, 0, 319.5, 0, 454.66, 179.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.26, 0.08, 0, 0, 0]
"""
CALIBRATIONS = {"opencv.yaml": OPENCV_YAML, "opencv.xml": OPENCV_XML, "camera_info.yaml": ROS_YAML}


@st.composite
def calibration_case(draw) -> tuple[str, bytes]:
    name = draw(st.sampled_from(sorted(CALIBRATIONS)))
    return name, draw(text_bytes([CALIBRATIONS[name]]))


def run_calibration(case: tuple[str, bytes]) -> str:
    from harborsight.geometry.calibration_files import load_camera_calibration

    name, data = case
    path = write_case(name, data)

    def load() -> None:
        intrinsics = load_camera_calibration(path)
        assert _finite([intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy,
                        *intrinsics.distortion])
        assert intrinsics.width >= 1 and intrinsics.height >= 1

    return _refused(load)


# -- drone logs and vessel tracks -------------------------------------------------------------

def _shared_texts(names: list[str]) -> list[str]:
    return [(SHARED_LOGS / "dji" / n).read_text(errors="replace") for n in names
            if (SHARED_LOGS / "dji" / n).is_file()]


SRT_TEXTS = [(LOGS / "flight.SRT").read_text()[:3000],
             *_shared_texts(["p4_rtk.SRT", "air2s.srt", "p4p_sample.SRT", "mavic_air2.srt"])]
SRT_TEXTS += [text[:4000] for text in _shared_texts(["matrice_300.srt", "mavic_mini.SRT",
                                                      "mavic_pro.SRT", "old_format.SRT"])]


def _check_track(track) -> None:
    assert len(track) >= 1, "a track without samples"
    for name in ("t_s", "lat_deg", "lon_deg", "attitude_t_s"):
        values = getattr(track, name)
        assert _finite(values), f"{name}: not finite: {values}"
    for name in ("alt_m", "heading_deg", "yaw_deg", "pitch_deg", "roll_deg"):
        values = getattr(track, name)   # NaN: a sample without it (Track.sample skips those)
        assert values is None or not np.isinf(values).any(), f"{name}: infinite: {values}"
    assert np.all(np.abs(track.lat_deg) <= 90) and np.all(np.abs(track.lon_deg) <= 180), (
        f"position out of range: {track.lat_deg}, {track.lon_deg}")


@st.composite
def srt_case(draw) -> tuple[bytes, float | None]:
    offset = draw(st.one_of(st.none(), st.floats(-14.0, 14.0)))
    return draw(text_bytes(SRT_TEXTS)), offset


def run_srt(case: tuple[bytes, float | None]) -> str:
    from harborsight.telemetry.dji_srt import read_dji_srt

    data, offset = case
    path = write_case("flight.SRT", data)
    return _refused(lambda: _check_track(read_dji_srt(path, utc_offset_h=offset)))


def nmea_sentence(body: str) -> str:
    """``$body*hh`` with its checksum."""
    from tests.helpers import nmea_checksum

    return f"${body}*{nmea_checksum(body)}"


field = st.one_of(st.sampled_from(["", "0", "A", "V", "N", "S", "E", "W", "T", "M", "nan",
                                   "99", "9" * 30, "1e308", "-0", "240101", "999999",
                                   "235959.99", "5609.102", "01013.698", "18000.0", "-9000.0"]),
                  st.text(alphabet="0123456789.-+ENSWTAV", max_size=12))


@st.composite
def nmea_line(draw) -> str:
    kind = draw(st.sampled_from(["GPRMC", "GPGGA", "HEHDT", "HCHDG", "HCHDM", "GNRMC", "XXABC"]))
    count = {"GPRMC": 12, "GNRMC": 12, "GPGGA": 14, "HEHDT": 2, "HCHDG": 5, "HCHDM": 2}.get(kind, 3)
    fields = [draw(field) for _ in range(draw(st.integers(max(count - 2, 0), count + 1)))]
    return nmea_sentence(",".join([kind, *fields]))


NMEA_TEXT = (LOGS / "ship.nmea").read_text()


@st.composite
def nmea_case(draw) -> bytes:
    lines = draw(mutated_text([NMEA_TEXT])).splitlines()
    for _ in range(draw(st.integers(0, 6))):
        lines.insert(draw(st.integers(0, len(lines))), draw(nmea_line()))
    return "\n".join(lines).encode("utf-8", "surrogatepass")


def run_nmea(data: bytes) -> str:
    from harborsight.telemetry.vessel_track import read_vessel_nmea

    path = write_case("ship.nmea", data)
    return _refused(lambda: _check_track(read_vessel_nmea(path)))


CSV_TEXT = "time,lat,lon,heading_deg\n" + "".join(
    f"2026-05-01T12:00:{i:02d}Z,56.1517,10.2283,{117 + i}\n" for i in range(6))
CSV_MAGNETIC = CSV_TEXT.replace("heading_deg", "heading_mag_deg")


def run_csv(data: bytes) -> str:
    from harborsight.telemetry.vessel_track import read_vessel_csv

    path = write_case("ship.csv", data)
    return _refused(lambda: _check_track(read_vessel_csv(path)))


@functools.cache
def log_seed(name: str) -> bytes:
    """A real autopilot log of ``../shared/data/telemetry``, or b"" when it is not there."""
    path = SHARED_LOGS / name
    return path.read_bytes() if path.is_file() else b""


def run_ulog(data: bytes) -> str:
    from harborsight.telemetry.autopilot import read_px4_ulog

    path = write_case("flight.ulg", data)
    return _refused(lambda: _check_track(read_px4_ulog(path)))


def run_dataflash(data: bytes) -> str:
    from harborsight.telemetry.autopilot import read_ardupilot_bin

    path = write_case("flight.BIN", data)
    return _refused(lambda: _check_track(read_ardupilot_bin(path)))



@functools.cache
def photo_seed() -> bytes:
    """A DJI photo with a full XMP packet (a Phantom 4 RTK's calibration and RTK fields) and
    EXIF, written by ElementTree and Pillow (tests/dji_photos.py)."""
    from tests.dji_photos import P4RTK_CALIBRATION, write_dji_photo

    rgb = np.random.default_rng(29).integers(0, 255, (48, 64, 3), np.uint8)
    xmp = {**P4RTK_CALIBRATION, "GpsLatitude": "+56.151608098", "GpsLongtitude": "+10.228217041",
           "RelativeAltitude": "+59.92", "AbsoluteAltitude": "+104.92",
           "GimbalYawDegree": "-30.33", "GimbalPitchDegree": "-87.57", "GimbalRollDegree": "+0.00",
           "RtkFlag": "50", "RtkStdLon": "0.01274", "RtkStdLat": "0.01122", "RtkStdHgt": "0.02394",
           "CalibratedOpticalCenterX": "32.0", "CalibratedOpticalCenterY": "24.0"}
    path = write_dji_photo(scratch() / "seed.jpg", rgb, xmp, exif={
        "DateTimeOriginal": "2026:05:01 14:00:05", "OffsetTimeOriginal": "+02:00",
        "FocalLength": 8.8, "FocalLengthIn35mmFilm": 24}, gps=(56.1516, 10.2282))
    return path.read_bytes()


def run_dji_photo(data: bytes) -> str:
    """A photo read, summarised and (where it has a pose) made a drone track: checked
    finite where it is taken."""
    from harborsight.telemetry.dji_photo import capture_utc, photo_track, read_dji_photo

    def read() -> None:
        photo = read_dji_photo(write_case("DJI_0001.JPG", data))
        json.dumps(photo.summary(), allow_nan=False, default=str)
        when, _ = capture_utc(photo, 2.0)
        _check_track(photo_track(photo, when=when))

    return _refused(read)


@functools.cache
def ais_seed() -> str:
    """An own-vessel AIS log with receiver tag blocks, another vessel and a two-part static
    report, written by pyais's encoder."""
    from pyais.encode import encode_dict

    from tests.helpers import ais_tag_block as tag

    start, lines = 1_777_636_800, []
    for k in range(12):
        report = {"type": 1, "mmsi": 219000001, "lat": 56.1517 - 1e-5 * k, "lon": 10.2283,
                  "heading": 118, "course": 117.7, "speed": 0.8, "second": (2 * k) % 60}
        lines.append(tag(start + 2 * k + 1.4) + encode_dict(report)[0])
        other = {"type": 18, "mmsi": 219999999, "lat": 56.2, "lon": 10.3, "heading": 10,
                 "second": 5}
        lines.append(tag(start + 2 * k + 1.5) + encode_dict(other, radio_channel="B")[0])
    lines += encode_dict({"type": 5, "mmsi": 219000001, "shipname": "HARBOUR TUG", "to_bow": 20,
                          "to_stern": 12, "to_port": 5, "to_starboard": 5}, seq_id=3)
    return "\n".join(lines) + "\n"


def run_ais(data: bytes) -> str:
    from harborsight.telemetry.ais import read_ais_dimensions, read_ais_track

    path = write_case("ship.ais", data)
    _refused(lambda: read_ais_dimensions(path, mmsi=219000001))
    return _refused(lambda: _check_track(read_ais_track(path, mmsi=219000001)))


@functools.cache
def bag_seed(kind: str) -> bytes:
    """The storage file of a bag of the bundled flight's poses (no images), written by
    rosbags (tests/ros_bags.py): ``ros1`` (.bag), ``sqlite3`` (.db3) or ``mcap``."""
    from tests.ros_bags import write_flight_bag

    folder = scratch() / f"seed-{kind}"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    bag = write_flight_bag(folder / ("flight.bag" if kind == "ros1" else "bag"), kind,
                           range(0, 48, 4), with_images=False)
    storage = bag if kind == "ros1" else next(p for p in bag.iterdir() if p.suffix != ".yaml")
    return storage.read_bytes()


def run_bag(suffix: str):
    def run(data: bytes) -> str:
        from harborsight.telemetry.rosbag import read_bag_track

        path = write_case("flight" + suffix, data)
        return _refused(lambda: _check_track(read_bag_track(path)))

    return run

# -- measure_frame on valid poses --------------------------------------------------------------

#: radial distortion k1 of the generated cameras: none, mild barrel or pincushion, and a
#: strong barrel lens (k1 -0.26, as in issue #30) whose fold the wide views reach
MILD_K1 = [0.0, 0.1, -0.05]
STRONG_K1 = [-0.26]


@st.composite
def pose_case(draw, k1_values: tuple[float, ...] = (*MILD_K1, *STRONG_K1),
              methods: tuple[str, ...] = ("ground_plane", "gsd"),
              fov_scale: tuple[float, float] = (0.5, 2.0)) -> dict:
    """A drone 15 to 400 m over the water looking down within 40 degrees of nadir, a vessel
    up to 150 m off under any heading, a camera with one of ``k1_values`` and a focal length
    of ``fov_scale`` times half the image width (0.5: 127 degrees across, 0.9: 96, 2.0: 53),
    a straight quay edge anywhere in the image, measured by one of ``methods``."""
    return {
        "alt_m": draw(st.floats(15.0, 400.0)), "water_level_m": draw(st.floats(-5.0, 5.0)),
        "pitch_deg": draw(st.floats(-90.0, -50.0)), "yaw_deg": draw(st.floats(-180.0, 180.0)),
        "roll_deg": draw(st.floats(-10.0, 10.0)),
        "east_m": draw(st.floats(-150.0, 150.0)), "north_m": draw(st.floats(-150.0, 150.0)),
        "heading_deg": draw(st.floats(0.0, 360.0)),
        "k1": draw(st.sampled_from(k1_values)),
        "fov_scale": draw(st.floats(*fov_scale)),
        "quay_point": (draw(st.floats(0.0, 1.0)), draw(st.floats(0.0, 1.0))),
        "quay_angle_deg": draw(st.floats(0.0, 360.0)),
        "method": draw(st.sampled_from(methods)),
        "box": draw(st.booleans()),
    }


WIDTH, HEIGHT = 256, 144


def pose_meta(case: dict):
    """The frame metadata of a :func:`pose_case`."""
    from harborsight.frame import FrameMetadata
    from harborsight.geometry.camera import CameraIntrinsics

    lat0, lon0 = 56.1517, 10.2283
    metres_per_deg_lat = 111_320.0
    metres_per_deg_lon = metres_per_deg_lat * math.cos(math.radians(lat0))
    focal = WIDTH / 2.0 * case["fov_scale"]
    camera = CameraIntrinsics(WIDTH, HEIGHT, focal, focal, (WIDTH - 1) / 2, (HEIGHT - 1) / 2,
                              (case["k1"], 0.0, 0.0, 0.0, 0.0))
    return FrameMetadata(
        image="fuzz.png", camera=camera, uav_lat_deg=lat0, uav_lon_deg=lon0,
        uav_alt_m=case["alt_m"] + case["water_level_m"], yaw_deg=case["yaw_deg"],
        pitch_deg=case["pitch_deg"], roll_deg=case["roll_deg"],
        vessel_lat_deg=lat0 + case["north_m"] / metres_per_deg_lat,
        vessel_lon_deg=lon0 + case["east_m"] / metres_per_deg_lon,
        vessel_heading_deg=case["heading_deg"], water_level_m=case["water_level_m"],
        timestamp=datetime(2026, 5, 1, 12).isoformat(), source="fuzz.json")


@functools.cache
def _vessels():
    from harborsight.vessel.spec import load_vessel_spec, parse_vessel_spec

    box = parse_vessel_spec(dict(VESSEL_DIMENSIONS), scratch() / "vessel.yaml")
    return box, load_vessel_spec(SAMPLES / "vessels" / "harbour-tug" / "vessel.yaml")


def pose_labels(case: dict, meta, vessel) -> np.ndarray:
    """Water, a quay beyond a straight edge, and the vessel drawn where its pose puts it."""
    import cv2

    from harborsight.frame import FrameGeometry

    labels = np.zeros((HEIGHT, WIDTH), np.uint8)
    u0, v0 = case["quay_point"][0] * WIDTH, case["quay_point"][1] * HEIGHT
    angle = math.radians(case["quay_angle_deg"])
    vv, uu = np.mgrid[0:HEIGHT, 0:WIDTH]
    labels[(uu - u0) * math.cos(angle) + (vv - v0) * math.sin(angle) > 0] = 2
    try:
        geometry = FrameGeometry.from_metadata(meta)
    except HarborsightError:
        return labels
    uv, valid = geometry.camera.project(geometry.vessel_to_enu(vessel.outline))
    if valid.all() and np.all(np.abs(uv) < 1e5):
        cv2.fillPoly(labels, [np.round(uv).astype(np.int32)], 1)
    return labels


def measure_report(case: dict):
    """The report of ``measure_frame`` on a :func:`pose_case`, its invariants checked: strict
    JSON, and every ``ok`` section with a finite, non-negative distance."""
    from harborsight.clearance.measure import ClearanceSettings, measure_frame
    from harborsight.files import strict_json

    box, tug = _vessels()
    vessel = box if case["box"] else tug
    meta = pose_meta(case)
    labels = pose_labels(case, meta, vessel)
    report = measure_frame(labels, meta, vessel, ClearanceSettings(method=case["method"]))
    text = strict_json(report.to_dict())
    json.loads(text, parse_constant=lambda name: (_ for _ in ()).throw(ValueError(name)))
    for section in report.sections:
        if section.status == "ok":
            where = f"section {section.index}: distance_m {section.distance_m}"
            assert section.distance_m is not None and math.isfinite(section.distance_m), where
            assert section.distance_m >= 0, where
            if section.distance_px is not None:
                assert math.isfinite(section.distance_px) and section.distance_px >= 0, (
                    f"section {section.index}: distance_px {section.distance_px}")
    return report


def run_measure(case: dict) -> str:
    return _refused(lambda: measure_report(case))



# -- annotation importers (dataset import) ----------------------------------------------------

#: the size of the importers' images, and their class names (all mapped)
ANN_H, ANN_W = 40, 60
ANN_MAP = {"boat": 1, "dock": 2, "wake": 255}


@functools.cache
def annotation_images() -> Path:
    """Two small images (``a.png``, ``b.jpg``) the annotation seeds name."""
    import cv2

    folder = scratch() / "ann-images"
    folder.mkdir(exist_ok=True)
    rng = np.random.default_rng(5)
    for name in ("a.png", "b.jpg"):
        assert cv2.imwrite(str(folder / name), rng.integers(0, 256, (ANN_H, ANN_W, 3), np.uint8))
    return folder


def _runs(flat: np.ndarray) -> list[int]:
    """Run lengths of a 0/1 sequence, zeros first (COCO's and CVAT's order)."""
    edges = np.flatnonzero(np.diff(flat)) + 1
    runs = np.diff(np.concatenate([[0], edges, [flat.size]])).tolist()
    return [0, *runs] if flat[0] else runs


def _patch() -> np.ndarray:
    patch = np.zeros((7, 10), np.uint8)
    patch[2:6, 1:9] = 1
    patch[0, 0] = 1
    return patch


@functools.cache
def coco_seed() -> dict:
    """Two images: a polygon, an uncompressed and a compressed RLE, a box-only annotation."""
    from pycocotools import mask as coco_mask

    blob = np.zeros((ANN_H, ANN_W), np.uint8)
    blob[20:35, 30:55] = 1
    compressed = coco_mask.encode(np.asfortranarray(blob))
    return {
        "images": [{"id": 1, "file_name": "a.png", "height": ANN_H, "width": ANN_W},
                   {"id": 2, "file_name": "b.jpg", "height": ANN_H, "width": ANN_W}],
        "categories": [{"id": 1, "name": "boat"}, {"id": 2, "name": "dock"}, {"id": 3, "name": "wake"}],
        "annotations": [
            {"id": 1, "image_id": 1, "category_id": 1, "iscrowd": 0, "area": 375.0,
             "bbox": [5, 5, 25, 15], "segmentation": [[5, 5, 30, 5, 30, 20, 5, 20],
                                                      [40, 2, 55, 2, 48, 12]]},
            {"id": 2, "image_id": 1, "category_id": 2, "iscrowd": 1, "area": 200.0,
             "bbox": [0, 25, 20, 10], "segmentation": {
                 "size": [ANN_H, ANN_W], "counts": _runs(np.pad(np.ones((10, 20), np.uint8),
                                                              ((25, 5), (0, 40))).T.ravel())}},
            {"id": 3, "image_id": 2, "category_id": 2, "iscrowd": 1, "area": 375.0,
             "bbox": [30, 20, 25, 15], "segmentation": {
                 "size": [ANN_H, ANN_W], "counts": compressed["counts"].decode()}},
            {"id": 4, "image_id": 2, "category_id": 3, "iscrowd": 0, "area": 20.0,
             "bbox": [1, 1, 5, 4], "segmentation": [[1, 1, 6, 1, 6, 5, 1, 5]]},
        ]}


@functools.cache
def labelme_seed() -> dict:
    """A polygon, a rectangle, a circle, a mask and a line strip (not a region)."""
    import base64

    import cv2

    ok, png = cv2.imencode(".png", _patch() * 255)
    assert ok
    shapes = [
        {"label": "boat", "shape_type": "polygon", "points": [[5, 5], [30, 5], [30, 20], [5, 20]]},
        {"label": "dock", "shape_type": "rectangle", "points": [[50.6, 30.2], [40.3, 20.7]]},
        {"label": "Wake", "shape_type": "circle", "points": [[12.2, 30.4], [12.2, 36.9]]},
        {"label": "boat", "shape_type": "mask", "points": [[3, 31], [12, 37]],
         "mask": base64.b64encode(png.tobytes()).decode()},
        {"label": "dock", "shape_type": "linestrip", "points": [[1, 1], [5, 5], [9, 1]]},
    ]
    return {"version": "5.4.1", "flags": {}, "imagePath": "a.png", "imageData": None,
            "imageHeight": ANN_H, "imageWidth": ANN_W,
            "shapes": [{"group_id": None, "flags": {}, "description": "", **s} for s in shapes]}


def cvat_seed() -> str:
    """Two images: boxes (one turned), a polygon, a mask, an ellipse, a polyline and a tag."""
    rle = ", ".join(str(r) for r in _runs(_patch().ravel()))
    first = ('<box label="dock" xtl="20" ytl="10" xbr="50" ybr="30" z_order="1" occluded="0"></box>'
             '<polygon label="boat" points="33.3,5.2;57.6,18.9;36.1,35.7" z_order="0"></polygon>'
             f'<mask label="boat" rle="{rle}" left="2" top="30" width="10" height="7" z_order="0"/>'
             '<box label="wake" xtl="0" ytl="0" xbr="8" ybr="6" z_order="2"/>'
             '<polyline label="dock" points="1,1;5,5"/><tag label="sunny"/>')
    second = ('<box label="boat" xtl="10" ytl="15" xbr="40" ybr="25" rotation="30"/>'
              '<ellipse label="dock" cx="48" cy="12" rx="9" ry="4" rotation="30"/>')
    body = "".join(f'\n  <image id="{k}" name="{name}" width="{ANN_W}" height="{ANN_H}">{shapes}</image>'
                   for k, (name, shapes) in enumerate((("a.png", first), ("b.jpg", second))))
    return (f'<?xml version="1.0" encoding="utf-8"?>\n<annotations>\n  <version>1.1</version>'
            f'{body}\n</annotations>\n')


YOLO_SEED = ("1 0.083333 0.100000 0.500000 0.100000 0.500000 0.300000 0.233333 0.300000\n"
             "0 0.555000 0.130000 0.960000 0.472500 0.601667 0.892500\n")
YOLO_SEED_B = "2 0.1 0.1 0.2 0.1 0.2 0.2\n0 0.5 0.5 0.9 0.5 0.9 0.9 0.5 0.9\n"
YOLO_CLASSES = "names:\n  0: boat\n  1: dock\n  2: wake\n"


def _check_import(result, out_dir: Path) -> None:
    """Every frame written is an image and a label mask of its size with harborsight's
    classes only, and dataset.json is strict JSON naming them."""
    import cv2

    doc = json.loads((out_dir / "dataset.json").read_text(), parse_constant=lambda c: 1 / 0)
    assert set(doc["split"]) == set(result.splits)
    for stem in result.splits:
        labels = cv2.imread(str(out_dir / "labels" / f"{stem}.png"), cv2.IMREAD_UNCHANGED)
        images = [p for p in (out_dir / "images").glob(f"{stem}.*")]
        assert labels is not None and labels.dtype == np.uint8 and labels.ndim == 2, stem
        assert len(images) == 1, (stem, images)
        image = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED)
        assert image is not None and image.shape[:2] == labels.shape, (stem, labels.shape)
        assert set(np.unique(labels).tolist()) <= {0, 1, 2, 255}, (stem, np.unique(labels))


def run_import(fmt: str, files: dict[str, bytes], classes: str | None = None) -> str:
    """Write ``files`` (name -> bytes) to a fresh folder and import them as ``fmt`` with the
    images of :func:`annotation_images`: read, refused as a whole, or frames skipped and
    named while the rest are written (checked by :func:`_check_import`)."""
    from harborsight.datasets import ImportOptions, import_dataset

    images = annotation_images()
    case = Path(tempfile.mkdtemp(prefix=f"import-{fmt}-", dir=scratch()))
    try:
        sources = []
        for name, data in files.items():
            path = case / "ann" / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
            sources.append(path)
        if fmt == "yolo-seg":
            sources = [case / "ann"]
            (case / "classes.yaml").write_text(classes or YOLO_CLASSES)
        options = ImportOptions(fmt, sources, case / "out", images_dir=images,
                                classes_path=case / "classes.yaml" if fmt == "yolo-seg" else None,
                                class_map=dict(ANN_MAP))
        try:
            result = import_dataset(options)
        except HarborsightError:
            return "refused"
        if not result.splits:
            return "refused"        # nothing written: every frame was skipped, and named
        assert len(result.skipped) + len(result.splits) >= 1
        _check_import(result, case / "out")
        return "ok"
    finally:
        shutil.rmtree(case, ignore_errors=True)


def _json_case(seed):
    """A seed document edited in its structure, or its text torn."""
    return st.one_of(edited_document(seed).map(lambda d: json.dumps(d).encode()),
                     text_bytes([json.dumps(seed, indent=1)]))


def run_coco(data: bytes) -> str:
    return run_import("coco", {"instances.json": data})


def run_labelme(data: bytes) -> str:
    return run_import("labelme", {"a.json": data})


def run_cvat(data: bytes) -> str:
    return run_import("cvat", {"annotations.xml": data})


def run_yolo(case: tuple[bytes, bytes, str]) -> str:
    first, second, classes = case
    return run_import("yolo-seg", {"a.txt": first, "b.txt": second}, classes)


yolo_case = st.tuples(text_bytes([YOLO_SEED]), text_bytes([YOLO_SEED_B]),
                      st.one_of(st.just(YOLO_CLASSES), mutated_text([YOLO_CLASSES])))


#: name: (strategy of cases, run)
TARGETS = {
    "frame-dict": (edited_document(FRAME), run_frame_dict),
    "frame-file": (text_bytes([FRAME_TEXT]), run_frame_file),
    "json-lines": (text_bytes([JSONL_TEXT, JSONL_INDEXED]), run_json_lines),
    "vessel-dict": (st.one_of(edited_document(VESSEL_DIMENSIONS), edited_document(VESSEL_MESH)),
                    run_vessel_doc),
    "vessel-file": (text_bytes([VESSEL_TEXT, json.dumps(VESSEL_DIMENSIONS)]), run_vessel_file),
    "calibration": (calibration_case(), run_calibration),
    "dji-srt": (srt_case(), run_srt),
    "nmea": (nmea_case(), run_nmea),
    "vessel-csv": (text_bytes([CSV_TEXT, CSV_MAGNETIC]), run_csv),
    "px4-ulog": (st.deferred(lambda: mutated_bytes(log_seed("px4/sample_log_small.ulg"))),
                 run_ulog),
    "ardupilot-bin": (st.deferred(lambda: mutated_bytes(log_seed("ardupilot/test.BIN"))),
                      run_dataflash),
    "dji-photo": (st.deferred(lambda: mutated_bytes(photo_seed())), run_dji_photo),
    "ais": (st.deferred(lambda: text_bytes([ais_seed()])), run_ais),
    "rosbag1": (st.deferred(lambda: mutated_bytes(bag_seed("ros1"))), run_bag(".bag")),
    "rosbag2-db3": (st.deferred(lambda: mutated_bytes(bag_seed("sqlite3"))), run_bag(".db3")),
    "rosbag2-mcap": (st.deferred(lambda: mutated_bytes(bag_seed("mcap"))), run_bag(".mcap")),
    "measure-frame": (pose_case(), run_measure),
    "coco": (st.deferred(lambda: _json_case(coco_seed())), run_coco),
    "labelme": (st.deferred(lambda: _json_case(labelme_seed())), run_labelme),
    "cvat": (st.deferred(lambda: text_bytes([cvat_seed()])), run_cvat),
    "yolo-seg": (yolo_case, run_yolo),
}
