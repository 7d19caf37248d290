"""Seeded 3-D harbour scenes for the Blender simulator (no bpy here): the five classic
scenarios, the parts they are built of (ships, quays, piers, buoys, breakwaters) and the
sampling of a scene, its camera and its environment; the scene's data is
:mod:`harborsight.sim.scene`.

Objects are built in a local right-handed frame (x forward, y left, z up) and placed at a
vessel-frame position ``(x_bow, y_starboard)`` with a heading relative to the vessel's bow
(clockwise), which maps local x to the ENU bearing ``heading + relative heading``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import trimesh
from scipy.spatial import ConvexHull
from shapely.geometry import MultiPoint, Polygon

from harborsight.geometry.camera import CameraIntrinsics
from harborsight.geometry.rotations import enu_from_vessel_rotation, rot_z
from harborsight.sim.scene import (
    OBSTACLE,
    SHIP,
    VESSEL_INSTANCE,
    Environment,
    HarbourScene,
    Material,
    Part,
    SceneObject,
)
from harborsight.vessel.hullgen import HullParameters, generate_hull_mesh
from harborsight.vessel.spec import VesselSpec

# ------------------------------------------------------------------------ primitives


_UNIT_BOX = trimesh.creation.box(extents=(1.0, 1.0, 1.0))


@lru_cache(maxsize=16)
def unit_cylinder(sections: int) -> trimesh.Trimesh:
    """trimesh's cylinder of radius 1 and height 1 (z from -0.5 to 0.5); shared, never
    modified. Its vertices times ``(r, r, h)`` are exactly those of a cylinder of radius
    ``r`` and height ``h`` (same faces), at a sixth of the cost of building one."""
    return trimesh.creation.cylinder(radius=1.0, height=1.0, sections=sections)


def convex_mesh(points: np.ndarray) -> trimesh.Trimesh:
    """The convex hull of ``points (n, 3)`` as a closed mesh with outward faces: scipy's
    Qhull triangles, each turned so that its normal agrees with its facet's outward normal
    (``ConvexHull.equations``). trimesh's ``convex_hull`` gives the same solid, but repairs
    and caches what a primitive does not need, at five times the cost (1.7 against 0.3 ms
    for an 8-point prism; a lake shore has dozens of prisms). The points must span a solid:
    Qhull refuses coplanar ones (``QhullError``), where trimesh would return a flat mesh."""
    hull = ConvexHull(points)
    used = np.unique(hull.simplices)
    faces = np.searchsorted(used, hull.simplices)
    vertices = points[used]
    corners = vertices[faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    inward = np.einsum("ij,ij->i", normal, hull.equations[:, :3]) < 0
    faces[inward] = faces[inward][:, ::-1]
    return trimesh.Trimesh(vertices, faces, process=False)


def _box(lx: float, ly: float, lz: float, x: float = 0.0, y: float = 0.0,
         z_bottom: float = 0.0) -> trimesh.Trimesh:
    """trimesh's box of these extents, moved: its base centred at ``(x, y, z_bottom)``."""
    vertices = _UNIT_BOX.vertices * np.array([lx, ly, lz])
    vertices += (x, y, z_bottom + lz / 2)
    return trimesh.Trimesh(vertices, _UNIT_BOX.faces.copy(), process=False)


def _cylinder(radius: float, height: float, x: float = 0.0, y: float = 0.0,
              z_bottom: float = 0.0, sections: int = 12) -> trimesh.Trimesh:
    """An upright cylinder standing on ``(x, y, z_bottom)``."""
    unit = unit_cylinder(sections)
    vertices = unit.vertices * np.array([radius, radius, height])
    vertices += (x, y, z_bottom + height / 2)
    return trimesh.Trimesh(vertices, unit.faces.copy(), process=False)


class _Builder:
    """Collects objects and materials; places local meshes in the world."""

    def __init__(self, rng: np.random.Generator, heading_deg: float,
                 view_reach_m: float | None = None) -> None:
        self.rng = rng
        self.heading_deg = heading_deg
        #: no camera of the scene sees (or is shaded from) farther than this from the
        #: vessel's origin; None: unknown. Filler that only fills the view (woods) stops there
        self.view_reach_m = view_reach_m
        #: a marina frame that looks along the berths (families.draw_berth_view); None: the
        #: camera aims at the vessel
        self.berth_view = None
        #: where the camera aims, off the vessel's origin (vessel frame, m)
        self.aim_v: tuple[float, float] = (0.0, 0.0)
        #: marinas of 3-6 rows a side with few empty berths (families.DENSE_MARINA);
        #: False: the sparser marinas of datasets rendered before
        self.dense_marinas = True
        self.r_enu_v = enu_from_vessel_rotation(math.radians(heading_deg))
        self.objects: list[SceneObject] = []
        self.materials: dict[str, Material] = {}
        self.next_instance = VESSEL_INSTANCE + 1

    def material(self, name: str, mat: Material) -> str:
        self.materials[name] = mat
        return name

    def place(self, mesh: trimesh.Trimesh, x_v: float, y_v: float, rel_heading_deg: float = 0.0
              ) -> trimesh.Trimesh:
        """Local (x fwd, y left, z up) -> W: rotate to bearing heading+rel, move to (x_v, y_v)."""
        bearing = math.radians(self.heading_deg + rel_heading_deg)
        transform = np.eye(4)
        transform[:3, :3] = rot_z(math.pi / 2 - bearing)
        transform[:3, 3] = self.r_enu_v @ np.array([x_v, y_v, 0.0])
        # the vertices Trimesh.apply_transform would give, without copying the mesh's caches
        return trimesh.Trimesh(trimesh.transformations.transform_points(mesh.vertices, transform),
                               mesh.faces.copy(), process=False)

    def add(self, name: str, kind: str, class_id: int, parts: list[tuple[trimesh.Trimesh, str]],
            x_v: float, y_v: float, rel_heading_deg: float = 0.0) -> SceneObject:
        obj = SceneObject(name, kind, class_id, self.next_instance, [
            Part(self.place(mesh, x_v, y_v, rel_heading_deg), mat) for mesh, mat in parts])
        self.next_instance += 1
        self.objects.append(obj)
        return obj


# ------------------------------------------------------------------------ palettes

_HULL_RGB = [(0.35, 0.02, 0.02), (0.02, 0.05, 0.25), (0.01, 0.12, 0.03), (0.02, 0.02, 0.02),
             (0.7, 0.7, 0.68), (0.6, 0.25, 0.01), (0.15, 0.04, 0.2), (0.03, 0.2, 0.35),
             (0.55, 0.45, 0.02)]
_DECK_RGB = [(0.25, 0.06, 0.04), (0.12, 0.16, 0.1), (0.3, 0.3, 0.28), (0.18, 0.12, 0.06)]
_CONTAINER_RGB = [(0.5, 0.05, 0.02), (0.02, 0.12, 0.4), (0.05, 0.25, 0.06), (0.6, 0.3, 0.02),
                  (0.6, 0.6, 0.6), (0.3, 0.02, 0.02), (0.02, 0.3, 0.3), (0.45, 0.45, 0.05)]
_WATER_RGB = [(0.015, 0.05, 0.06), (0.02, 0.07, 0.05), (0.03, 0.05, 0.04), (0.01, 0.03, 0.06),
              (0.04, 0.06, 0.04), (0.02, 0.04, 0.045)]


def _jitter(rgb: tuple[float, float, float], rng: np.random.Generator, amount: float = 0.15
            ) -> tuple[float, float, float]:
    scale = rng.uniform(1 - amount, 1 + amount, 3)
    return tuple(float(np.clip(c * s, 0.0, 1.0)) for c, s in zip(rgb, scale, strict=True))


def _grey(rgb: tuple[float, float, float], rng: np.random.Generator, amount: float
          ) -> tuple[float, float, float]:
    """Brightness jitter with a faint tint only (concrete, rock, steel stay grey)."""
    scale = rng.uniform(1 - amount, 1 + amount) * rng.uniform(0.96, 1.04, 3)
    return tuple(float(np.clip(c * s, 0.0, 1.0)) for c, s in zip(rgb, scale, strict=True))


@dataclass(frozen=True)
class HullRanges:
    """Where a kind of hull's proportions are drawn from (shares of the length unless said)."""

    beam: tuple[float, float] = (0.17, 0.3)
    deckhouse_start: tuple[float, float] = (0.1, 0.55)
    draft_share: float = 0.09
    draft_min_m: float = 0.5
    freeboard: tuple[float, float] = (0.04, 0.08)
    freeboard_limits_m: tuple[float, float] = (0.5, 6.0)
    bow_fraction: tuple[float, float] = (0.18, 0.4)
    flare: tuple[float, float] = (0.0, 0.18)       # share of the beam
    deckhouse_width: tuple[float, float] = (0.45, 0.8)   # share of the beam
    deckhouse_height: tuple[float, float] = (0.06, 0.15)
    deckhouse_height_limits_m: tuple[float, float] = (1.5, 12.0)


#: ships and workboats (the classic scenes)
SHIP_HULLS = HullRanges()


def random_hull_parameters(rng: np.random.Generator, length_m: float,
                           ranges: HullRanges = SHIP_HULLS) -> HullParameters:
    """A plausible hull of the given length (beam, draft, freeboard, deckhouse drawn)."""
    beam = length_m * rng.uniform(*ranges.beam)
    start = rng.uniform(*ranges.deckhouse_start)
    return HullParameters(
        length_m=length_m, beam_m=beam, draft_m=max(ranges.draft_min_m, ranges.draft_share * length_m),
        freeboard_m=float(np.clip(length_m * rng.uniform(*ranges.freeboard), *ranges.freeboard_limits_m)),
        bow_fraction=rng.uniform(*ranges.bow_fraction), flare=rng.uniform(*ranges.flare),
        deckhouse=(start, min(start + rng.uniform(0.15, 0.35), 0.8), rng.uniform(*ranges.deckhouse_width),
                   float(np.clip(length_m * rng.uniform(*ranges.deckhouse_height),
                                 *ranges.deckhouse_height_limits_m))),
    )


# ------------------------------------------------------------------------ objects


def _ship_parts(b: _Builder, params: HullParameters, tag: str) -> list[tuple[trimesh.Trimesh, str]]:
    """A moored ship in local axes, centred on its midship: hull, deck, deckhouse, mast."""
    rng = b.rng
    mesh = generate_hull_mesh(params)
    # generate_hull_mesh returns hull + deckhouse concatenated; split them for materials
    pieces = mesh.split(only_watertight=False)
    pieces = sorted(pieces, key=lambda m: -m.extents[0])
    hull, rest = pieces[0], pieces[1:]
    hull_mat = b.material(f"{tag}-hull", Material(_jitter(_HULL_RGB[rng.integers(len(_HULL_RGB))],
                                                          rng), rng.uniform(0.35, 0.7), 0.1, 0.12))
    house_mat = b.material(f"{tag}-house", Material(
        _jitter((0.75, 0.74, 0.7), rng, 0.1) if rng.random() < 0.75
        else _jitter(_HULL_RGB[rng.integers(len(_HULL_RGB))], rng), rng.uniform(0.3, 0.6), 0.0, 0.06))
    deck_mat = b.material(f"{tag}-deck", Material(_jitter(_DECK_RGB[rng.integers(len(_DECK_RGB))],
                                                          rng), 0.8, 0.0, 0.25, 1.5))
    shift = np.array([-params.length_m / 2, 0.0, 0.0])
    parts = [(hull, hull_mat)] + [(m, house_mat) for m in rest]
    # deck plate: the hull's top cut shrunk a little, a few cm proud of the hull
    top = hull.vertices[hull.vertices[:, 2] >= hull.vertices[:, 2].max() - 1e-6]
    deck_poly = MultiPoint(top[:, :2]).convex_hull.buffer(-0.06 * params.beam_m)
    if isinstance(deck_poly, Polygon) and not deck_poly.is_empty:
        ring = np.asarray(deck_poly.exterior.coords)[:-1]
        deck = trimesh.convex.convex_hull(np.vstack((
            np.column_stack((ring, np.full(len(ring), params.freeboard_m))),
            np.column_stack((ring, np.full(len(ring), params.freeboard_m + 0.05))))))
        parts.append((deck, deck_mat))
    if params.length_m > 15 and rng.random() < 0.7:
        start, end = params.deckhouse[:2]
        x_mast = 0.5 * (start + end) * params.length_m
        parts.append((_cylinder(0.12 + 0.004 * params.length_m, params.deckhouse[3] * 0.8,
                                x_mast, 0.0, params.freeboard_m + params.deckhouse[3]), house_mat))
    for mesh, _ in parts:
        mesh.apply_translation(shift)
    return parts


def add_ship(b: _Builder, x_v: float, y_v: float, params: HullParameters,
             rel_heading_deg: float, kind: str = "ship") -> SceneObject:
    tag = f"{kind}{b.next_instance}"
    return b.add(tag, kind, SHIP, _ship_parts(b, params, tag), x_v, y_v, rel_heading_deg)


def max_half_beam(params: HullParameters) -> float:
    """Half beam at the deck (flare included), metres."""
    return 0.5 * params.beam_m * (1.0 + params.flare)


def add_quay(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float, tag: str,
             fender_radius_m: float, depth_m: float = 60.0, length_m: float = 500.0
             ) -> list[SceneObject]:
    """A quay whose water-side face runs through vessel-frame (x_v, y_v) along the bearing
    ``rel_heading_deg`` from the bow, land on the right of that direction, water on the left;
    fenders on its face, bollards, container stacks, a shed and a crane on it."""
    rng = b.rng
    rel = rel_heading_deg
    height = rng.uniform(1.2, 3.0)
    concrete = b.material(f"{tag}-concrete", Material(_grey((0.32, 0.31, 0.29), rng, 0.35),
                                                      0.85, 0.0, 0.3, 0.3))
    # local frame: x along the face, y (left) toward the water
    slab = _box(length_m, depth_m, height + 4.0, 0.0, -depth_m / 2, -4.0)
    objects = [b.add(tag, "quay", OBSTACLE, [(slab, concrete)], x_v, y_v, rel)]

    def at(x_local: float, y_local: float) -> tuple[float, float]:
        """Local quay coordinates to the vessel frame: local x is (cos a, sin a) in
        (bow, starboard), local y (its left) is (sin a, -cos a)."""
        a = math.radians(rel)
        return (x_v + x_local * math.cos(a) + y_local * math.sin(a),
                y_v + x_local * math.sin(a) - y_local * math.cos(a))

    rubber = b.material(f"{tag}-rubber", Material((0.015, 0.015, 0.015), 0.9, 0.0, 0.05))
    spacing = rng.uniform(8.0, 16.0)
    radius = fender_radius_m
    offset = rng.uniform(0, spacing)
    for x in np.arange(-120.0 + offset, 120.0, spacing):
        fender = _cylinder(radius, height + 0.8, 0.0, 0.0, -0.8)
        xv, yv = at(float(x), radius)
        objects.append(b.add(f"{tag}-fender{len(objects)}", "fender", OBSTACLE,
                             [(fender, rubber)], xv, yv, rel))
    iron = b.material(f"{tag}-iron", Material(_jitter((0.05, 0.05, 0.06), rng), 0.5, 0.6, 0.1))
    for x in np.arange(-120.0 + rng.uniform(0, 20), 120.0, rng.uniform(12.0, 25.0)):
        xv, yv = at(float(x), -1.2)
        bollard = _cylinder(0.3, 0.6, 0.0, 0.0, height, 10)
        objects.append(b.add(f"{tag}-bollard{len(objects)}", "bollard", OBSTACLE,
                             [(bollard, iron)], xv, yv, rel))
    # containers in stacks, sheds and a crane, set back from the edge
    for _ in range(int(rng.integers(2, 10))):
        x = rng.uniform(-110, 110)
        y = -rng.uniform(8.0, depth_m - 8.0)
        n_high = int(rng.integers(1, 4))
        colour = _CONTAINER_RGB[rng.integers(len(_CONTAINER_RGB))]
        mat = b.material(f"{tag}-cont{len(objects)}", Material(_jitter(colour, rng), 0.5, 0.3,
                                                               0.2, 1.2))
        length = 12.19 if rng.random() < 0.6 else 6.06
        stack = [_box(length, 2.44, 2.59, 0.0, 0.0, height + 2.59 * k) for k in range(n_high)]
        xv, yv = at(x, y)
        objects.append(b.add(f"{tag}-containers{len(objects)}", "containers", OBSTACLE,
                             [(m, mat) for m in stack], xv, yv, rel + rng.choice([0.0, 90.0])))
    if rng.random() < 0.6:
        shed_mat = b.material(f"{tag}-shed", Material(_grey((0.4, 0.42, 0.45), rng, 0.3), 0.5,
                                                      0.4, 0.1, 0.8))
        lx, ly, lz = rng.uniform(20, 60), rng.uniform(12, 25), rng.uniform(6, 12)
        xv, yv = at(rng.uniform(-90, 90), -(10 + ly / 2 + rng.uniform(0, 15)))
        objects.append(b.add(f"{tag}-shed", "shed", OBSTACLE,
                             [(_box(lx, ly, lz, 0, 0, height), shed_mat)], xv, yv, rel))
    if rng.random() < 0.5:
        crane_mat = b.material(f"{tag}-crane", Material(_jitter(
            [(0.6, 0.35, 0.01), (0.5, 0.02, 0.02), (0.05, 0.15, 0.35)][rng.integers(3)], rng),
            0.5, 0.5, 0.05))
        gauge, span, tall = rng.uniform(10, 18), rng.uniform(12, 20), rng.uniform(20, 35)
        legs = [_box(1.2, 1.2, tall, sx * span / 2, -4.0 - sy * gauge, height)
                for sx in (-1, 1) for sy in (0, 1)]
        beams = [_box(span + 1.2, 1.5, 1.5, 0, -4.0 - sy * gauge, height + tall) for sy in (0, 1)]
        boom = _box(2.0, gauge + 22.0, 2.0, 0, -13.0 - gauge / 2, height + tall + 1.5)
        xv, yv = at(rng.uniform(-80, 80), 0.0)
        objects.append(b.add(f"{tag}-crane", "crane", OBSTACLE,
                             [(m, crane_mat) for m in [*legs, *beams, boom]], xv, yv, rel))
    return objects


def quay_face_offset(hull_xy: np.ndarray, side: int, clearance_m: float, fender_m: float,
                     skew_deg: float) -> float:
    """Where a quay face on ``side`` (+1 starboard) crosses the vessel frame's y axis so that
    every hull point is ``clearance_m`` plus the fender's thickness (``2 fender_m``) from it:
    the face is ``y(x) = E + x tan(skew)``, ``E = side (clearance + 2 fender + max(side (y -
    x tan(skew))))`` over the hull points."""
    tan = math.tan(math.radians(skew_deg))
    need = max(side * y - side * x * tan for x, y in hull_xy)
    return side * (clearance_m + 2 * fender_m + need)


@dataclass(frozen=True)
class QuayAlongside:
    """What :func:`add_quay_alongside` placed: the face's offset and skew, the fenders'
    radius and the quay's objects."""

    edge_m: float
    skew_deg: float
    fender_m: float
    objects: list[SceneObject]


def add_quay_alongside(b: _Builder, hull_xy: np.ndarray, side: int, clearance_m: float,
                       skew_deg: float, tag: str, skip_ship: float = 0.25,
                       ship_length_m: tuple[float, float] = (12.0, 60.0),
                       ship_spacing_m: tuple[float, float] = (3.0, 25.0)) -> QuayAlongside:
    """A quay (:func:`add_quay`) along the vessel on ``side``, its fenders ``clearance_m`` off
    the hull, and ships moored ahead and astern along its face, clear of the fenders (each
    left out with probability ``skip_ship``)."""
    rng = b.rng
    fender = float(rng.uniform(0.3, 0.6))
    edge = quay_face_offset(hull_xy, side, clearance_m, fender, skew_deg)
    tan = math.tan(math.radians(skew_deg))
    objects = add_quay(b, 0.0, edge, (0.0 if side > 0 else 180.0) + skew_deg, tag, fender)
    x_min, x_max = float(hull_xy[:, 0].min()), float(hull_xy[:, 0].max())
    for direction in (1, -1):
        if rng.random() < skip_ship:
            continue
        params = random_hull_parameters(rng, float(rng.uniform(*ship_length_m)))
        end = x_max if direction > 0 else x_min
        cx = end + direction * (rng.uniform(*ship_spacing_m) + params.length_m / 2)
        cy = edge + cx * tan - side * (2 * fender + 0.3 + max_half_beam(params))
        _try_add(b, lambda p=params, x=cx, y=cy: add_ship(
            b, x, y, p, skew_deg + float(rng.choice([0.0, 180.0]))), 0.0)
    return QuayAlongside(edge, skew_deg, fender, objects)


def add_buoy(b: _Builder, x_v: float, y_v: float) -> SceneObject:
    rng = b.rng
    colour = [(0.6, 0.01, 0.01), (0.01, 0.35, 0.03), (0.7, 0.5, 0.0), (0.02, 0.02, 0.02)][
        rng.integers(4)]
    mat = b.material(f"buoy{b.next_instance}", Material(_jitter(colour, rng), 0.4, 0.0, 0.05))
    radius = rng.uniform(0.6, 1.4)
    parts = [(_cylinder(radius, 1.2 + radius, 0, 0, -0.8, 16), mat)]
    if rng.random() < 0.6:
        cone = trimesh.creation.cone(radius * 0.7, 1.6 * radius, sections=12)
        cone.apply_translation((0, 0, 0.4 + radius))
        parts.append((cone, mat))
    return b.add(f"buoy{b.next_instance}", "buoy", OBSTACLE, parts, x_v, y_v)


def add_pier(b: _Builder, x_v: float, y_v: float, length_m: float, rel_heading_deg: float
             ) -> SceneObject:
    rng = b.rng
    wood = b.material(f"pier{b.next_instance}", Material(_jitter((0.22, 0.15, 0.09), rng, 0.3),
                                                         0.9, 0.0, 0.35, 2.0))
    width = rng.uniform(2.5, 6.0)
    deck = _box(length_m, width, 0.4, length_m / 2, 0, rng.uniform(0.8, 1.8))
    piles = [_cylinder(0.25, 2.5, x, s * (width / 2 - 0.3), -1.0, 8)
             for x in np.arange(1.0, length_m, 6.0) for s in (-1, 1)]
    return b.add(f"pier{b.next_instance}", "pier", OBSTACLE,
                 [(deck, wood), *((p, wood) for p in piles)], x_v, y_v, rel_heading_deg)


def add_breakwater(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float) -> SceneObject:
    """A rubble-mound breakwater: a long trapezoid prism of rock."""
    rng = b.rng
    rock = b.material(f"rock{b.next_instance}", Material(_grey((0.2, 0.19, 0.17), rng, 0.3),
                                                         0.95, 0.0, 0.5, 1.0))
    top_w, slope, height, length = rng.uniform(4, 10), rng.uniform(1.2, 2.0), rng.uniform(2, 5), 300.0
    half_base = top_w / 2 + slope * (height + 3.0)
    section = [(-half_base, -3.0), (half_base, -3.0), (top_w / 2, height), (-top_w / 2, height)]
    prism = trimesh.convex.convex_hull(np.array([(x, y, z) for x in (0.0, length)
                                                 for y, z in section]))
    return b.add(f"breakwater{b.next_instance}", "breakwater", OBSTACLE, [(prism, rock)],
                 x_v, y_v, rel_heading_deg)


# ------------------------------------------------------------------------ the vessel


#: the length range of the classic scenes' vessels of interest (tugs to small ships), and of
#: the leisure vessels a lake shore or a marina centres on (day boats to motor yachts)
VESSEL_LENGTH_M = (18.0, 70.0)
LEISURE_LENGTH_M = (6.0, 16.0)
#: pool vessels named so are leisure craft: drawn for the families in LEISURE_FAMILIES
LEISURE_VESSEL_PREFIX = "sim-leisure-"
LEISURE_FAMILIES = ("lakeshore", "marina")


def generate_vessel(rng: np.random.Generator, name: str, out_dir,
                    length_m: tuple[float, float] = VESSEL_LENGTH_M,
                    ranges: HullRanges = SHIP_HULLS) -> HullParameters:
    """Write a procedural vessel (``hull.stl`` + ``vessel.yaml``) of a length drawn from
    ``length_m`` and proportions from ``ranges`` to ``out_dir``."""
    import yaml  # local: only the dataset writer needs it

    length = float(rng.uniform(*length_m))
    params = random_hull_parameters(rng, length, ranges)
    out_dir.mkdir(parents=True, exist_ok=True)
    generate_hull_mesh(params).export(out_dir / "hull.stl")
    start, end, _, house_h = params.deckhouse
    antenna = [round(0.5 * (start + end) * length, 3), 0.0,
               round(params.freeboard_m + house_h, 3)]
    (out_dir / "vessel.yaml").write_text(
        f"# Procedural vessel from harborsight.sim (hullgen), {length:.1f} m. Mesh in naval CAD\n"
        "# axes: origin at the transom on the centreline, z = 0 at the waterline.\n"
        + yaml.safe_dump({"name": name, "hull_mesh": "hull.stl", "mesh_axes": ["bow", "port", "up"],
                          "gps_antenna": antenna, "waterline_m": 0.0, "outline": "waterline",
                          "sections": 16}, sort_keys=False))
    return params


def _vessel_object(b: _Builder, vessel: VesselSpec) -> SceneObject:
    """The vessel of interest from its spec's mesh (V frame -> W), one material per piece."""
    if vessel.mesh is None:
        raise ValueError(f"{vessel.source}: the simulator needs a vessel spec with hull_mesh")
    rng = b.rng
    pieces = sorted(vessel.mesh.split(only_watertight=False), key=lambda m: -m.area)
    hull_mat = b.material("vessel-hull", Material(
        _jitter(_HULL_RGB[rng.integers(len(_HULL_RGB))], rng), rng.uniform(0.3, 0.7), 0.1, 0.12))
    house_mat = b.material("vessel-house", Material(_jitter((0.78, 0.77, 0.74), rng, 0.1), 0.4,
                                                    0.0, 0.05))
    parts = []
    for i, piece in enumerate(pieces or [vessel.mesh]):
        world = piece.copy()
        world.vertices = world.vertices @ b.r_enu_v.T   # antenna at the W origin
        parts.append(Part(world, hull_mat if i == 0 else house_mat))
    obj = SceneObject("vessel", "vessel", SHIP, VESSEL_INSTANCE, parts)
    b.objects.insert(0, obj)
    return obj


# ------------------------------------------------------------------------ sampling

SCENARIOS = {"alongside": 0.3, "slip": 0.25, "pass": 0.15, "touching": 0.1, "open": 0.2}
#: scene families that look like real harbours (harborsight.sim.families); never drawn unless
#: asked for, so that the classic draws (and every dataset rendered with them) stay the same
FAMILIES = ("lakeshore", "marina", "commercial", "fishing")


def _overlaps(candidate: SceneObject, others: list[SceneObject], margin_m: float) -> bool:
    fp = candidate.footprint().buffer(margin_m)
    return any(fp.intersects(o.footprint()) for o in others)


def _try_add(b: _Builder, make, margin_m: float = 0.5) -> SceneObject | None:
    """Add an object unless its footprint overlaps one already placed (then drop it)."""
    obj = make()
    others = [o for o in b.objects if o is not obj]
    if _overlaps(obj, others, margin_m):
        b.objects.remove(obj)
        return None
    return obj


def view_reach(altitude_m: float, intrinsics: CameraIntrinsics, max_tilt_deg: float) -> float:
    """How far from the vessel's origin a frame's camera can see on the water, with margin.
    The camera aims at a point up to ``0.1 h`` off the vessel per axis (:func:`_with_camera`),
    and a ray ``t + θ`` off the vertical (``θ = atan(r_corner / f)``, the image corner; ``t``
    the tilt, plus 3 degrees of roll) meets the water ``h (tan(t + θ) - tan t)`` from that
    point, at most ``h tan(t + θ)``. Plus :data:`VIEW_REACH_MARGIN_M` for what casts a
    shadow into the view or reaches in from beyond (a tree's crown). A marina frame along the
    berths aims farther off; the marinas' shores have no woods, the only filler this bounds."""
    corner_px = math.hypot(intrinsics.width / 2, intrinsics.height / 2)
    off_axis = math.atan(corner_px / min(intrinsics.fx, intrinsics.fy)) + math.radians(max_tilt_deg + 3.0)
    if off_axis >= math.radians(80.0):
        return math.inf
    return altitude_m * (math.tan(off_axis) + 0.1 * math.sqrt(2.0)) + VIEW_REACH_MARGIN_M


#: metres added to :func:`view_reach`: a 24 m tree's shadow with the sun 31 degrees up
VIEW_REACH_MARGIN_M = 40.0


def sample_harbour_scene(
    vessel: VesselSpec, vessel_dir_name: str, rng: np.random.Generator, *, altitude_m: float,
    intrinsics: CameraIntrinsics, max_tilt_deg: float = 15.0, scenario: str | None = None,
    name: str = "scene", timestamp: str | None = None,
    leisure_paint: np.random.Generator | None = None,
    berth_view_rng: np.random.Generator | None = None, dense_marinas: bool = True,
) -> HarbourScene:
    """A seeded harbour around ``vessel`` and a drone camera above it.

    Scenarios: ``alongside`` a quay, ``slip`` between moored ships, ``pass`` a pier head
    close by, ``touching`` a moored neighbour, ``open`` water with buoys and a breakwater.
    Close passes (gaps 0 to 5 m) are 40 % of the gaps drawn. The families (``lakeshore``,
    ``marina``, ``commercial``, ``fishing``: :mod:`harborsight.sim.families`) only when asked
    for by name. ``leisure_paint``: in a family of :data:`LEISURE_FAMILIES`, the vessel is a
    leisure craft, painted with draws from this generator (not ``rng``: the scene's other
    draws stay those of an unpainted one). ``berth_view_rng``: in a marina, whether the
    camera looks along the berths and where (``families.BERTH_VIEW_SHARE``), drawn from this
    generator, so that the scene is the one drawn without it. ``dense_marinas``: see
    ``families.DENSE_MARINA``.
    """
    scenario = scenario or str(rng.choice(list(SCENARIOS), p=list(SCENARIOS.values())))
    if scenario not in SCENARIOS and scenario not in FAMILIES:
        raise ValueError(f"unknown scenario {scenario!r}; choose from "
                         f"{sorted(SCENARIOS) + list(FAMILIES)}")
    heading = float(rng.uniform(0.0, 360.0))
    b = _Builder(rng, heading, view_reach_m=view_reach(altitude_m, intrinsics, max_tilt_deg))
    b.dense_marinas = dense_marinas
    if scenario == "marina" and berth_view_rng is not None:
        from harborsight.sim.families import draw_berth_view

        b.berth_view = draw_berth_view(berth_view_rng)
    _vessel_object(b, vessel)
    hull_xy = vessel.hull_points[:, :2]
    x_min, x_max = float(hull_xy[:, 0].min()), float(hull_xy[:, 0].max())
    side = int(rng.choice([-1, 1]))
    gap = float(rng.uniform(0.0, 5.0) if rng.random() < 0.4 else rng.uniform(5.0, 20.0))

    def half_beam(s: int) -> float:
        return float(hull_xy[:, 1].max() if s > 0 else -hull_xy[:, 1].min())

    def quay_alongside(s: int, clearance: float, skew_deg: float, tag: str) -> None:
        add_quay_alongside(b, hull_xy, s, clearance, skew_deg, tag)

    if scenario in FAMILIES:
        from harborsight.sim import families

        hull = Polygon(vessel.outline)
        build = {"lakeshore": families.build_lakeshore, "marina": families.build_marina,
                 "commercial": families.build_commercial_quay,
                 "fishing": families.build_fishing_harbour}[scenario]
        if scenario in LEISURE_FAMILIES and leisure_paint is not None:
            families.paint_leisure_vessel(b, leisure_paint)
        build(b, hull, hull_xy, side, gap)
        families.add_boats_under_way(b, hull, int(rng.integers(0, 3)), gap)
        families.keep_gap(b, gap)
        env = families.sample_realistic_environment(rng, scenario)
        return _with_camera(b, vessel, vessel_dir_name, rng, heading, altitude_m, intrinsics,
                            max_tilt_deg, env, scenario, gap, name, timestamp)
    if scenario in ("alongside", "touching"):
        clearance = gap
        if scenario == "touching":
            gap = 0.0
            params = random_hull_parameters(rng, float(rng.uniform(15, 50)))
            cy = side * (half_beam(side) + max_half_beam(params))
            add_ship(b, float(rng.uniform(-5, 5)), cy, params, float(rng.choice([0.0, 180.0])))
            clearance = 2 * max_half_beam(params) + rng.uniform(0.0, 1.5)
        quay_alongside(side, clearance, float(rng.uniform(-2, 2)), "quay")
    elif scenario == "slip":
        for s in (-1, 1):
            g = gap if s == side else float(rng.uniform(3, 15))
            params = random_hull_parameters(rng, float(rng.uniform(25, 70)))
            cy = s * (half_beam(s) + g + max_half_beam(params))
            add_ship(b, float(rng.uniform(-10, 10)), cy, params, float(rng.choice([0.0, 180.0])))
        add_quay(b, x_max + rng.uniform(30, 70), 0.0, -90.0 + rng.uniform(-5, 5), "quay",
                 float(rng.uniform(0.3, 0.6)))
    elif scenario == "pass":
        length = float(rng.uniform(15, 40))
        x0 = float(rng.uniform(x_min, x_max))
        y0 = side * (half_beam(side) + gap)
        add_pier(b, x0, y0, length, 90.0 if side > 0 else -90.0)
        add_quay(b, x0, side * (half_beam(side) + gap + length), (0.0 if side > 0 else 180.0)
                 + rng.uniform(-3, 3), "quay", float(rng.uniform(0.3, 0.6)))
    else:  # open water
        corner_x = x_max + rng.uniform(20, 60)
        add_breakwater(b, corner_x, side * rng.uniform(15, 40), float(rng.uniform(-30, 30)))

    # clutter: buoys and small boats in the water around, never on top of anything
    hull = Polygon(vessel.outline)
    n_buoys = int(rng.integers(0, 3)) + (4 if scenario == "open" else 0)
    for _ in range(n_buoys):
        ring = hull.buffer(rng.uniform(2.0, 35.0), quad_segs=8).exterior
        p = ring.interpolate(rng.uniform(0, 1), normalized=True)
        _try_add(b, lambda x=p.x, y=p.y: add_buoy(b, x, y), 1.0)
    for _ in range(int(rng.integers(0, 4))):
        ring = hull.buffer(rng.uniform(5.0, 60.0), quad_segs=8).exterior
        p = ring.interpolate(rng.uniform(0, 1), normalized=True)
        params = random_hull_parameters(rng, float(rng.uniform(5, 12)))
        _try_add(b, lambda x=p.x, y=p.y, pr=params: add_ship(
            b, x, y, pr, float(rng.uniform(0, 360)), kind="boat"), 1.0)

    env = sample_environment(rng)
    return _with_camera(b, vessel, vessel_dir_name, rng, heading, altitude_m, intrinsics,
                        max_tilt_deg, env, scenario, gap if scenario != "open" else None, name,
                        timestamp)


def _with_camera(b: _Builder, vessel: VesselSpec, vessel_dir_name: str, rng: np.random.Generator,
                 heading: float, altitude_m: float, intrinsics: CameraIntrinsics,
                 max_tilt_deg: float, env: Environment, scenario: str, gap: float | None,
                 name: str, timestamp: str | None) -> HarbourScene:
    """The scene with a drone camera drawn above the vessel, or above ``b.aim_v`` off it
    where a family's builder moved the aim (a marina's view along the berths)."""
    # camera: above the vessel with a horizontal offset and a random yaw; the tilt off nadir
    # is a gimbal pitch toward the yaw direction; a small roll turns the image
    tilt = float(rng.uniform(0.0, max_tilt_deg))
    yaw = float(rng.uniform(0.0, 360.0))
    roll = float(rng.uniform(-3.0, 3.0))
    offset = rng.uniform(-0.1, 0.1, 2) * altitude_m
    look = np.array([math.sin(math.radians(yaw)), math.cos(math.radians(yaw))])
    ahead = altitude_m * math.tan(math.radians(tilt)) * look
    aim = (b.r_enu_v @ np.array([b.aim_v[0], b.aim_v[1], 0.0]))[:2]
    uav = np.array([aim[0] + offset[0] - ahead[0], aim[1] + offset[1] - ahead[1], altitude_m])
    return HarbourScene(
        name=name, vessel=vessel, vessel_dir_name=vessel_dir_name, vessel_heading_deg=heading,
        objects=b.objects, materials=b.materials, intrinsics=intrinsics, uav_enu=uav,
        yaw_deg=yaw, pitch_deg=-90.0 + tilt, roll_deg=roll, environment=env,
        scenario=scenario, gap_m=gap, timestamp=timestamp,
    )


def sample_environment(rng: np.random.Generator) -> Environment:
    """Time of day, weather and water: the paper's domain randomisation."""
    overcast = rng.random() < 0.3
    return Environment(
        sun_elevation_deg=float(rng.uniform(12.0, 75.0)),
        sun_azimuth_deg=float(rng.uniform(0.0, 360.0)),
        sun_strength=float(rng.uniform(1.0, 2.0) if overcast else rng.uniform(3.0, 6.0)),
        sky_turbidity=float(rng.uniform(5.0, 10.0) if overcast else rng.uniform(2.0, 5.0)),
        water_rgb=_jitter(_WATER_RGB[rng.integers(len(_WATER_RGB))], rng, 0.35),
        water_roughness=float(rng.uniform(0.02, 0.25)),
        wave_scale=float(rng.uniform(0.05, 0.6)),
        wind_mps=float(rng.uniform(2.0, 14.0)),
        choppiness=float(rng.uniform(0.5, 1.5)),
        foam_coverage=float(rng.uniform(0.0, 0.5)),
        ripple_strength=float(rng.uniform(0.1, 0.6)),
        ocean_seed=int(rng.integers(0, 2**16)),
        haze=float(rng.uniform(0.0, 0.15) if not overcast else rng.uniform(0.05, 0.25)),
        haze_rgb=_jitter((0.75, 0.78, 0.82), rng, 0.1),
        exposure_ev=float(rng.uniform(-0.3, 0.7)),
        noise_sigma=float(rng.uniform(0.5, 4.0)),
    )
