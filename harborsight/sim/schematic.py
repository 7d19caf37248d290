"""Schematic harbour frames drawn from exact geometry (until the Blender simulator lands).

A scene is a set of flat footprints on the water plane (quays, piers, moored ships, buoys)
around the vessel of interest, seen by a posed camera. Every pixel centre is back-projected
onto the water plane and labelled by the footprint that contains it, so the label mask is
exact for any camera tilt; the vessel of interest is drawn as the image of its whole 3-D
hull (the convex hull of its projected points), so it hides what lies behind it as a real
vessel would. Ground truth per section comes from shapely on the same footprints
(:mod:`harborsight.sim.ground_truth`).

Nothing here is photorealistic: RGB colours are flat with light procedural texture. It
exercises the geometry, not the segmentation.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import shapely
from shapely import affinity
from shapely.geometry import MultiPoint, Polygon, box

from harborsight.geometry.camera import CameraIntrinsics
from harborsight.geometry.geodesy import GeoOrigin
from harborsight.sim.ground_truth import frame_ground_truth, vessel_silhouette
from harborsight.sim.pose import PosedScene
from harborsight.sim.scene import VESSEL_INSTANCE
from harborsight.vessel.spec import VesselSpec

SHIP, OBSTACLE = 1, 2

#: DJI Mavic 3 (4/3" sensor 17.3 x 13.0 mm, 12.29 mm lens, 24 mm equiv.), video crop to 16:9,
#: scaled to 640x360: fx = 12.29 / 17.3 * 640 = 454.7 px.
DEFAULT_INTRINSICS = CameraIntrinsics(640, 360, 454.7, 454.7, 319.5, 179.5)

WATER_BGR = np.array([112.0, 84.0, 38.0])


@dataclass
class Footprint:
    """A flat solid on the water plane, in ENU metres."""

    polygon: Polygon
    class_id: int
    instance_id: int
    kind: str
    colour_bgr: tuple[int, int, int]
    deck: Polygon | None = None          # painted only (superstructure seen from above)
    deck_colour_bgr: tuple[int, int, int] = (235, 235, 235)


@dataclass
class SchematicScene(PosedScene):
    """Everything needed to render one frame and its ground truth."""

    name: str
    vessel: VesselSpec
    vessel_heading_deg: float
    footprints: list[Footprint]
    intrinsics: CameraIntrinsics
    uav_enu: np.ndarray                  # camera centre relative to the vessel antenna, metres
    yaw_deg: float
    pitch_deg: float
    roll_deg: float = 0.0
    origin: GeoOrigin = field(default_factory=lambda: GeoOrigin(56.1517, 10.2283, 0.0))
    timestamp: str | None = None
    seed: int = 0                        # texture noise


def _pixel_grid(intr: CameraIntrinsics) -> np.ndarray:
    u, v = np.meshgrid(np.arange(intr.width, dtype=float), np.arange(intr.height, dtype=float))
    return np.column_stack((u.ravel(), v.ravel()))


def render(scene: SchematicScene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RGB (BGR uint8), class labels (uint8) and instance ids (uint16), pixel-exact."""
    geometry = scene.geometry()
    intr = scene.intrinsics
    grid = _pixel_grid(intr)
    ground, valid = geometry.camera.back_project_to_plane(grid)
    x, y = ground[:, 0], ground[:, 1]
    n_px = len(grid)
    labels = np.zeros(n_px, np.uint8)
    instances = np.zeros(n_px, np.uint16)
    rng = np.random.default_rng(scene.seed)

    # water: colour with swell and ripples as functions of ground position
    swell = np.sin(0.35 * x + 0.2 * y) + 0.5 * np.sin(0.9 * x - 0.7 * y + 1.3)
    colour = WATER_BGR[None, :] * (1.0 + 0.06 * np.nan_to_num(swell))[:, None]
    colour[~valid] = (200, 190, 170)
    labels[~valid] = 255

    for fp in scene.footprints:
        inside = valid & shapely.contains_xy(fp.polygon, x, y)
        labels[inside] = fp.class_id
        instances[inside] = fp.instance_id
        texture = 1.0 + 0.05 * np.sin(1.7 * x[inside]) * np.sin(1.3 * y[inside])
        colour[inside] = np.asarray(fp.colour_bgr, float)[None, :] * texture[:, None]
        if fp.deck is not None:
            on_deck = inside & shapely.contains_xy(fp.deck, x, y)
            colour[on_deck] = fp.deck_colour_bgr

    # the vessel of interest: the image of its whole hull
    silhouette = vessel_silhouette(scene.vessel, geometry)
    own = shapely.contains_xy(silhouette, grid[:, 0], grid[:, 1])
    labels[own] = SHIP
    instances[own] = VESSEL_INSTANCE
    colour[own] = (60, 60, 170)
    outline_enu = geometry.vessel_to_enu(scene.vessel.outline)
    outline_px = geometry.camera.project(outline_enu)[0]
    if not np.isfinite(outline_px).all():
        # part of a long hull lies behind an oblique camera: its image, cut there
        outline_px = geometry.camera.project_convex_outline(outline_enu)
    deck = Polygon(outline_px).buffer(-2.0) if len(outline_px) >= 3 else Polygon()
    if not deck.is_empty:
        colour[shapely.contains_xy(deck, grid[:, 0], grid[:, 1]) & own] = (150, 160, 165)

    colour += rng.normal(0.0, 4.0, colour.shape)
    image = np.clip(colour, 0, 255).astype(np.uint8).reshape(intr.height, intr.width, 3)
    image = cv2.GaussianBlur(image, (3, 3), 0.6)
    return (image, labels.reshape(intr.height, intr.width),
            instances.reshape(intr.height, intr.width))


def ground_truth(scene: SchematicScene, n_sections: int | None = None) -> dict:
    """Per-section exact distances (design.md ``ground_truth``) and the true poses."""
    geometry = scene.geometry()
    per_section = frame_ground_truth(geometry, scene.vessel,
                                     [fp.polygon for fp in scene.footprints], n_sections)
    return {
        "sections": per_section,
        "vessel_pose": {"lat": scene.origin.lat_deg, "lon": scene.origin.lon_deg,
                        "heading_deg": scene.vessel_heading_deg},
        "uav_enu_m": [float(v) for v in scene.uav_enu],
        "n_sections": len(per_section),
    }


# ----------------------------------------------------------------------------- layouts

_SHIP_COLOURS = [(40, 40, 150), (150, 90, 30), (30, 110, 30), (20, 20, 20), (200, 200, 200),
                 (30, 130, 200), (90, 60, 120)]


def _ship(center_v: tuple[float, float], length: float, beam: float, angle_deg: float,
          colour, instance: int) -> tuple[Polygon, Polygon]:
    """A moored ship footprint (pointed bow) and its deckhouse, in the vessel frame."""
    half_l, half_b = length / 2, beam / 2
    hull = Polygon([(half_l, 0), (half_l - beam, half_b), (-half_l, half_b),
                    (-half_l, -half_b), (half_l - beam, -half_b)])
    house = box(-0.3 * half_l, -0.6 * half_b, 0.2 * half_l, 0.6 * half_b)
    hull = affinity.translate(affinity.rotate(hull, angle_deg, origin=(0, 0)), *center_v)
    house = affinity.translate(affinity.rotate(house, angle_deg, origin=(0, 0)), *center_v)
    return hull, house


@dataclass
class LayoutParams:
    """Where things stand around the vessel (vessel frame: x bow, y starboard, metres)."""

    scenario: str = "alongside"          # alongside | slip | open | touching
    side: int = 1                         # +1 starboard, -1 port
    gap_m: float = 6.0


def sample_scene(
    vessel: VesselSpec, rng: np.random.Generator, *, altitude_m: float,
    tilt_deg: float = 0.0, scenario: str | None = None, gap_m: float | None = None,
    intrinsics: CameraIntrinsics = DEFAULT_INTRINSICS, name: str = "scene",
    timestamp: str | None = None,
) -> SchematicScene:
    """A seeded harbour layout around ``vessel`` and a camera above it."""
    scenario = scenario or str(rng.choice(["alongside", "slip", "open", "touching"]))
    side = int(rng.choice([-1, 1]))
    gap = float(gap_m if gap_m is not None else rng.uniform(1.0, 8.0))
    half_beam_side = vessel.outline[:, 1].max() if side > 0 else -vessel.outline[:, 1].min()
    x_min, x_max = vessel.outline[:, 0].min(), vessel.outline[:, 0].max()
    polys: list[tuple[Polygon, int, str, tuple, Polygon | None]] = []

    def quay(offset_y: float, sign: int, skew_deg: float = 0.0) -> Polygon:
        y0 = sign * offset_y
        strip = box(-400, min(y0, y0 + sign * 60), 400, max(y0, y0 + sign * 60))
        return affinity.rotate(strip, skew_deg, origin=(0, y0))

    def moored_ship(cx: float, cy: float, angle: float, length: float,
                    beam: float | None = None) -> None:
        beam = beam or length * rng.uniform(0.16, 0.24)
        colour = _SHIP_COLOURS[int(rng.integers(len(_SHIP_COLOURS)))]
        hull, house = _ship((cx, cy), length, beam, angle, colour, 0)
        polys.append((hull, SHIP, "ship", colour, house))

    if scenario in ("alongside", "touching"):
        wall = half_beam_side + gap
        if scenario == "touching":
            length = rng.uniform(25, 45)
            beam = length * 0.2
            cy = side * (half_beam_side + beam / 2)
            moored_ship(rng.uniform(-5, 5), cy, 0.0, length, beam)
            wall = half_beam_side + beam + rng.uniform(0.0, 2.0)
        polys.append((quay(wall, side, rng.uniform(-4, 4)), OBSTACLE, "quay", (120, 125, 128), None))
        for x0 in (x_max + rng.uniform(6, 25), x_min - rng.uniform(6, 25)):
            length = rng.uniform(20, 40)
            cx = x0 + (length / 2 if x0 > 0 else -length / 2)
            moored_ship(cx, side * (wall - length * 0.11 - 0.5), 0.0, length)
    elif scenario == "slip":
        for s in (-1, 1):
            hb = vessel.outline[:, 1].max() if s > 0 else -vessel.outline[:, 1].min()
            g = gap if s == side else rng.uniform(3, 12)
            length = rng.uniform(35, 60)
            beam = length * 0.2
            moored_ship(rng.uniform(-10, 10), s * (hb + g + beam / 2), rng.uniform(-3, 3), length,
                        beam)
        polys.append((box(x_max + rng.uniform(25, 60), -80, x_max + 140, 80), OBSTACLE, "quay",
                      (120, 125, 128), None))
    else:  # open water: buoys and a breakwater corner
        hull = Polygon(vessel.outline)
        for _ in range(int(rng.integers(3, 7))):
            ring = hull.buffer(rng.uniform(2.0, 25.0), quad_segs=8).exterior
            centre = ring.interpolate(rng.uniform(0, 1), normalized=True)
            radius = rng.uniform(0.8, 1.5)
            if centre.distance(hull) < radius + 1.0 or any(
                centre.distance(p[0]) < radius + 1.0 for p in polys):
                continue
            polys.append((centre.buffer(radius, quad_segs=16), OBSTACLE, "buoy", (30, 30, 200),
                          None))
        corner = (x_max + rng.uniform(20, 50), side * rng.uniform(15, 35))
        bw = Polygon([corner, (corner[0] + 200, corner[1]), (corner[0] + 200, corner[1] + side * 200),
                      (corner[0], corner[1] + side * 200)])
        polys.append((affinity.rotate(bw, rng.uniform(-20, 20), origin=corner), OBSTACLE,
                      "breakwater", (105, 110, 100), None))

    heading_deg = float(rng.uniform(0, 360))
    heading = math.radians(heading_deg)
    s, c = math.sin(heading), math.cos(heading)

    def to_enu(poly: Polygon) -> Polygon:
        # V (x bow, y starboard) -> ENU: e = x sin h + y cos h, n = x cos h - y sin h
        return shapely.transform(poly, lambda xy: np.column_stack((
            xy[:, 0] * s + xy[:, 1] * c, xy[:, 0] * c - xy[:, 1] * s)))

    vessel_poly = Polygon(vessel.outline)
    footprints = []
    for i, (poly, class_id, kind, colour, deck) in enumerate(polys):
        poly = poly.difference(vessel_poly) if poly.intersects(vessel_poly) else poly
        if poly.is_empty:
            continue
        footprints.append(Footprint(
            to_enu(poly), class_id, i + 2, kind, colour,
            None if deck is None else to_enu(deck),
        ))

    # camera: above the vessel with a horizontal offset and random yaw; the tilt off nadir
    # is a gimbal pitch toward the yaw direction (roll turns the image about its axis)
    offset = rng.uniform(-0.12, 0.12, 2) * altitude_m
    yaw = float(rng.uniform(0, 360))
    pitch = -90.0 + tilt_deg
    roll = float(rng.uniform(-3.0, 3.0))
    look = np.array([math.sin(math.radians(yaw)), math.cos(math.radians(yaw))])
    ahead = altitude_m * math.tan(math.radians(tilt_deg)) * look  # where the optical axis lands
    uav = np.array([offset[0] - ahead[0], offset[1] - ahead[1], altitude_m])
    return SchematicScene(
        name=name, vessel=vessel, vessel_heading_deg=heading_deg, footprints=footprints,
        intrinsics=intrinsics, uav_enu=uav, yaw_deg=yaw, pitch_deg=pitch, roll_deg=roll,
        timestamp=timestamp, seed=int(rng.integers(2**31)),
    )


def write_frame(scene: SchematicScene, dataset_dir: Path, stem: str,
                vessel_dir_name: str | None = None) -> dict:
    """Write ``images/``, ``labels/``, ``instances/`` and ``frames/`` entries for a scene."""
    image, labels, instances = render(scene)
    for sub in ("images", "labels", "instances", "frames"):
        (dataset_dir / sub).mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(dataset_dir / "images" / f"{stem}.png"), image)
    cv2.imwrite(str(dataset_dir / "labels" / f"{stem}.png"), labels)
    cv2.imwrite(str(dataset_dir / "instances" / f"{stem}.png"), instances)
    meta = scene.metadata(f"{stem}.png").to_dict()
    meta["ground_truth"] = ground_truth(scene)
    if vessel_dir_name:
        meta["vessel_spec"] = f"vessels/{vessel_dir_name}/vessel.yaml"
    (dataset_dir / "frames" / f"{stem}.json").write_text(json.dumps(meta, indent=2) + "\n")
    return meta


def flat_vessel(vessel: VesselSpec) -> VesselSpec:
    """The same vessel with no height: its hull points are its outline on the water."""
    pts = MultiPoint(vessel.outline).convex_hull.exterior.coords
    hull_points = np.column_stack((np.asarray(pts)[:-1], np.zeros(len(pts) - 1)))
    return VesselSpec(vessel.name, vessel.outline, hull_points, vessel.n_sections,
                      vessel.section_length_m, vessel.source, outline_sigma_m=vessel.outline_sigma_m)
