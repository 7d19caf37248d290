"""Small builders shared by the tests."""

from __future__ import annotations

import json
import random
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from harborsight.vessel.outline import outline_from_dimensions
from harborsight.vessel.spec import VesselSpec


def nmea_checksum(body: str) -> str:
    """The two hex digits of an NMEA 0183 checksum: the XOR of the body's bytes."""
    checksum = 0
    for char in body.encode("ascii", "replace"):
        checksum ^= char
    return f"{checksum:02X}"


def ais_tag_block(seconds: float) -> str:
    """An NMEA 4.10 tag block stamping a line with a receiver's UNIX time (``c:``)."""
    body = f"s:rx1,c:{seconds:.0f}"
    return f"\\{body}*{nmea_checksum(body)}\\"


#: the MMSI of the class B transponder :func:`class_b_ais_log` writes
CLASS_B_MMSI = 235000001


def class_b_ais_log(path, nmea_path, sentence_type: str = "VDM"):
    """The vessel of an NMEA log (the bundled flight's ship) as a class B transponder under
    2 kn gives it: a type 18 report at its first fix, with the speed and course of its first
    two, and the next 180 s later where that motion carries it; each received 0.3 s after
    its fix. Returns ``path``."""
    from pyais.encode import encode_dict
    from pyproj import Geod

    from harborsight.telemetry.vessel_track import read_vessel_track

    nmea = read_vessel_track(nmea_path)
    geod = Geod(ellps="WGS84")
    course, _, step_m = geod.inv(nmea.lon_deg[0], nmea.lat_deg[0], nmea.lon_deg[1], nmea.lat_deg[1])
    speed_mps = step_m / (nmea.t_s[1] - nmea.t_s[0])
    lines = []
    for after_s in (0.0, 180.0):
        lon, lat, _ = geod.fwd(nmea.lon_deg[0], nmea.lat_deg[0], course, speed_mps * after_s)
        when = nmea.utc_start.timestamp() + after_s
        report = {"type": 18, "mmsi": CLASS_B_MMSI, "lat": lat, "lon": lon,
                  "heading": round(nmea.heading_deg[0]), "second": round(when) % 60,
                  "speed": round(speed_mps * 3600 / 1852, 1), "course": round(course % 360, 1)}
        lines.append(ais_tag_block(when + 0.3) + encode_dict(report, sentence_type=sentence_type)[0])
    path.write_text("\n".join(lines) + "\n")
    return path


def flat_box_vessel(n_sections: int = 16) -> VesselSpec:
    """A 40 m x 10 m pointed-bow vessel with no height (the planar case)."""
    outline = outline_from_dimensions(30.0, 10.0, 5.0, 5.0)
    hull_points = np.column_stack((outline, np.zeros(len(outline))))
    return VesselSpec("test-boat", outline, hull_points, n_sections)



def generated_hull_vessel(folder: Path, hull, antenna: tuple[float, float, float],
                          sections: int, name: str = "hull") -> VesselSpec:
    """A vessel spec read from ``folder``: a procedural hull (``hull``, a
    :class:`~harborsight.vessel.hullgen.HullParameters`) written as STL in naval CAD axes,
    the GPS antenna at ``antenna`` (m, bow/port/up from the transom at the waterline)."""
    from harborsight.vessel.hullgen import generate_hull_mesh
    from harborsight.vessel.spec import load_vessel_spec

    folder = Path(folder)
    generate_hull_mesh(hull).export(folder / "hull.stl")
    (folder / "vessel.yaml").write_text(
        f"name: {name}\nhull_mesh: hull.stl\nmesh_axes: [bow, port, up]\n"
        f"gps_antenna: [{antenna[0]}, {antenna[1]}, {antenna[2]}]\nwaterline_m: 0.0\n"
        f"outline: waterline\nsections: {sections}\n")
    return load_vessel_spec(folder / "vessel.yaml")

def write_schematic_dataset(out_dir, splits: list[str], width: int = 128, height: int = 72,
                            seed: int = 0) -> list[str]:
    """A tiny dataset in the simulator layout: one schematic frame per entry of ``splits``
    (its split name), a nadir camera with a 90 degree horizontal field of view, 40-80 m up."""
    import json
    from pathlib import Path

    from harborsight.geometry.camera import CameraIntrinsics
    from harborsight.sim.schematic import sample_scene, write_frame

    out_dir = Path(out_dir)
    focal_px = width / 2.0  # tan(45 deg) = 1
    intrinsics = CameraIntrinsics(width, height, focal_px, focal_px, (width - 1) / 2,
                                  (height - 1) / 2)
    rng = np.random.default_rng(seed)
    vessel = flat_box_vessel()
    split_map = {}
    for i, split in enumerate(splits):
        stem = f"{i:06d}"
        scene = sample_scene(vessel, rng, altitude_m=float(rng.uniform(40.0, 80.0)),
                             intrinsics=intrinsics, name=stem)
        write_frame(scene, out_dir, stem)
        split_map[stem] = split
    (out_dir / "dataset.json").write_text(json.dumps({
        "generator": "tests.helpers.write_schematic_dataset", "seed": seed,
        "classes": {"0": "water", "1": "ship", "2": "obstacle", "255": "ignore"},
        "split": split_map}, indent=2))
    return list(split_map)


def torn_copies(whole: bytes, trials: int = 200, seed: int = 29) -> Iterator[tuple[int, int, bytes]]:
    """``(trial, cut, data)``: ``whole`` cut at a random byte, and on odd trials with one to
    three bits flipped before the cut (a file torn in a crash, then salted by a bad card)."""
    rng = random.Random(seed)
    for trial in range(trials):
        cut = rng.randrange(len(whole))
        data = bytearray(whole[:cut])
        if trial % 2:
            for _ in range(rng.randrange(1, 4)):
                if data:
                    data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
        yield trial, cut, bytes(data)


def pixel_of_camera_block(block: dict, point_camera: tuple[float, float, float]) -> np.ndarray:
    """Where OpenCV projects a camera-frame point with a frame/1 ``camera`` block (its
    intrinsics and distortion): an independent check of intrinsics written by the code."""
    import cv2

    k = np.array([[block["fx"], 0, block["cx"]], [0, block["fy"], block["cy"]], [0, 0, 1]])
    uv, _ = cv2.projectPoints(np.array([[point_camera]], float), np.zeros(3), np.zeros(3), k,
                              np.array(block["distortion"], float))
    return uv.ravel()



def side_view(off_m: float, alt_m: float, depression_deg: float,
              size: tuple[int, int] = (1280, 720), focal_px: float = 914.0):
    """A camera ``off_m`` west of a vessel at the origin heading north, ``alt_m`` up, looking
    east ``depression_deg`` below the horizon (90: nadir; the vessel's port side faces it).
    Returns the frame's geometry and ``to_px(points_v)``: vessel-frame points as pixel
    coordinates in 1/16 px, for ``cv2.fillPoly(..., shift=4)``."""
    from harborsight.frame import FrameGeometry
    from harborsight.geometry.camera import Camera, CameraIntrinsics
    from harborsight.geometry.geodesy import GeoOrigin
    from harborsight.geometry.rotations import world_from_camera_rotation

    width, height = size
    intrinsics = CameraIntrinsics(width, height, focal_px, focal_px, (width - 1) / 2, (height - 1) / 2)
    camera = Camera(intrinsics, np.array([-off_m, 0.0, alt_m]),
                    world_from_camera_rotation(np.radians(90.0), np.radians(-depression_deg), 0.0))
    geometry = FrameGeometry(GeoOrigin(56.0, 10.0, 0.0), camera, 0.0)

    def to_px(points_v: np.ndarray) -> np.ndarray:
        return np.round(camera.project(geometry.vessel_to_enu(points_v))[0] * 16).astype(np.int32)

    return geometry, to_px


def draw_vessel_as_seen(labels: np.ndarray, mesh_v, to_px) -> None:
    """Paint the part of a V-frame mesh above the waterline into ``labels`` as ship (1),
    face by face: what the vessel hides in the image, without any hull taken."""
    import cv2

    above = mesh_v.slice_plane([0, 0, 0], [0, 0, -1])
    for triangle in above.vertices[above.faces]:
        cv2.fillConvexPoly(labels, to_px(triangle), 1, cv2.LINE_8, shift=4)


def copy_sample_frames(samples: Path, dest: Path, count: int) -> Path:
    """The first ``count`` bundled sample frames (JSON beside its image) in ``dest``."""
    dest.mkdir()
    for path in sorted((samples / "frames").glob("*.json"))[:count]:
        (dest / path.name).write_text(path.read_text())
        image = json.loads(path.read_text())["image"]
        (dest / image).write_bytes((samples / "images" / image).read_bytes())
    return dest
