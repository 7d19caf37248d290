"""A lake or river shore (:func:`build_lakeshore`): land, rip-rap, lawns, roads, houses and
cars, woods and single trees, private docks with boat lifts and jet-ski ports."""

from __future__ import annotations

import math

import numpy as np
import trimesh
from shapely.geometry import Polygon

from harborsight.sim.families._parts import (
    _CAR_RGB,
    _COVER_RGB,
    _gable,
    _local_to_vessel,
    _overlaps_others,
    _pick,
    _planks,
    _prism,
)
from harborsight.sim.families.boats import add_leisure_boat
from harborsight.sim.layout import _box, _Builder, _cylinder, _grey, _jitter
from harborsight.sim.scene import OBSTACLE, Material

_ROOF_RGB = [(0.15, 0.15, 0.16), (0.3, 0.08, 0.05), (0.4, 0.4, 0.4), (0.12, 0.14, 0.2),
             (0.35, 0.3, 0.25)]
_UNIT_SPHERE = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
#: a crown's lobes are rounder (320 faces, not 80): their facets showed at 40 m
_LOBE_SPHERE = trimesh.creation.icosphere(subdivisions=2, radius=1.0)


def _ellipsoid(radius_xy: float, radius_z: float, z_centre: float, x: float = 0.0,
               y: float = 0.0, unit: trimesh.Trimesh = _UNIT_SPHERE) -> trimesh.Trimesh:
    vertices = unit.vertices * np.array([radius_xy, radius_xy, radius_z])
    vertices += (x, y, z_centre)
    return trimesh.Trimesh(vertices, unit.faces.copy(), process=False)


def _crown_lobes(radius_m: float, z_centre: float, rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """A tree's crown as real canopy looks from above: a lumpy mass of leaf clusters, not one
    smooth ellipsoid. A central lobe of 0.6-0.75 r and 4-7 lobes of 0.35-0.55 r around it,
    their centres 0.3-0.6 r out at evenly spread bearings (jittered) and from 0.3 r lower to
    0.15 r higher, each flattened to 0.6-0.9 of its radius. Every lobe is convex (the
    scene's rule); together they stay within about 1.15 r of the trunk. Their own shading
    and the shadows they cast on each other give the crown its clumps."""
    lobes = [_ellipsoid(radius_m * rng.uniform(0.6, 0.75), radius_m * rng.uniform(0.45, 0.6),
                        z_centre, unit=_LOBE_SPHERE)]
    n = int(rng.integers(4, 8))
    start = rng.uniform(0.0, 2 * math.pi)
    for k in range(n):
        bearing = start + 2 * math.pi * k / n + rng.uniform(-0.35, 0.35)
        out = radius_m * rng.uniform(0.3, 0.6)
        lobe_r = radius_m * rng.uniform(0.35, 0.55)
        lobes.append(_ellipsoid(lobe_r, lobe_r * rng.uniform(0.6, 0.9),
                                z_centre + radius_m * rng.uniform(-0.3, 0.15),
                                out * math.cos(bearing), out * math.sin(bearing), _LOBE_SPHERE))
    return lobes


def add_shore(b: _Builder, origin_v: tuple[float, float], along_deg: float, tag: str,
              length_m: float = 360.0, depth_m: float = 140.0, wooded_share: float = 0.0):
    """Land whose waterline runs through ``origin_v`` along ``along_deg`` (water on the left
    of that direction, land on the right), with a wavy edge, a lawn, a rip-rap or sand band,
    trees (some over the water), houses, a road and cars; with probability ``wooded_share``
    woods over the land behind the waterline (:func:`_add_woods`; no draw at 0). Returns the
    waterline as a function of the local x (along the shore; local y toward the water), for
    docks to start from."""
    rng = b.rng
    height = rng.uniform(0.4, 1.6)
    lawn = b.material(f"{tag}-lawn", Material(
        _jitter(_pick([(0.07, 0.14, 0.03), (0.12, 0.2, 0.04), (0.1, 0.16, 0.05), (0.16, 0.16, 0.08)],
                      rng), rng, 0.15), 0.9, 0.0, 0.35, rng.uniform(0.2, 0.6)))
    # the waterline: y_edge(x) wavy, land for y < y_edge
    xs = np.linspace(-length_m / 2, length_m / 2, 25)
    wave = rng.uniform(0.5, 4.0)
    edge = wave * np.sin(xs / rng.uniform(15, 40) + rng.uniform(0, 6)) + rng.normal(0, wave / 3, len(xs))
    edge = np.clip(edge, -1.5 * wave, 1.5 * wave)     # at most 6 m off the nominal waterline
    parts = []
    for k in range(len(xs) - 1):
        quad = np.array([(xs[k], edge[k]), (xs[k + 1], edge[k + 1]),
                         (xs[k + 1], -depth_m), (xs[k], -depth_m)])
        parts.append(_prism(quad, -3.0, height))
    objects_land = [(p, lawn) for p in parts]
    x0, y0 = _local_to_vessel(origin_v, along_deg, 0.0, 0.0)
    b.add(f"{tag}-land", "land", OBSTACLE, objects_land, x0, y0, along_deg)

    def place(x: float, y: float) -> tuple[float, float]:
        return _local_to_vessel(origin_v, along_deg, x, y)

    def edge_at(x: float) -> float:
        return float(np.interp(x, xs, edge))

    # rip-rap or sand along parts of the waterline
    if rng.random() < 0.6:
        rock = b.material(f"{tag}-riprap", Material(_grey((0.22, 0.2, 0.18), rng, 0.3), 0.95, 0.0, 0.6, 2.5))
        for k in range(len(xs) - 1):
            if rng.random() < 0.5:
                continue
            w = rng.uniform(1.5, 4.0)
            quad = np.array([(xs[k], edge[k] + w * 0.6), (xs[k + 1], edge[k + 1] + w * 0.6),
                             (xs[k + 1], edge[k + 1] - w), (xs[k], edge[k] - w)])
            slab = _prism(quad, -1.0, height + 0.3, top_xy=quad[2:])
            b.add(f"{tag}-riprap{k}", "riprap", OBSTACLE, [(slab, rock)], x0, y0, along_deg)
    # trees: trunks on land, crowns overhanging the water near the edge (and their shadows)
    bark = b.material(f"{tag}-bark", Material((0.08, 0.05, 0.03), 0.9))
    clumps = rng.uniform(-length_m / 2 + 10, length_m / 2 - 10, int(rng.integers(3, 9)))
    for _ in range(int(rng.integers(20, 70))):      # in clumps along the shore, as in the photos
        x = float(np.clip(rng.choice(clumps) + rng.normal(0, 10), -length_m / 2 + 5, length_m / 2 - 5))
        back = float(rng.exponential(12.0)) + 0.5
        _add_tree(b, tag, place(x, edge_at(x) - back), along_deg, float(rng.uniform(2.0, 7.0)),
                  height, bark)
    # a road behind the houses, houses with gabled roofs, cars on drives
    road_y = -rng.uniform(40.0, 80.0)
    asphalt = b.material(f"{tag}-asphalt", Material(_grey((0.06, 0.06, 0.065), rng, 0.3), 0.8, 0.0, 0.2, 1.0))
    xv, yv = place(0.0, road_y)
    b.add(f"{tag}-road", "road", OBSTACLE, [(_box(length_m, rng.uniform(6, 9), 0.08, 0, 0, height), asphalt)],
          xv, yv, along_deg)
    wall = b.material(f"{tag}-wall", Material(_jitter(_pick([(0.6, 0.55, 0.45), (0.7, 0.7, 0.68),
                                                             (0.35, 0.2, 0.12)], rng), rng), 0.7))
    clearings: list[tuple[float, float, float, float]] = []     # house centres, half sizes
    x = -length_m / 2 + rng.uniform(5, 25)
    while x < length_m / 2 - 15:
        lx, ly = rng.uniform(9, 18), rng.uniform(8, 14)
        y = road_y + ly / 2 + rng.uniform(8, 25)
        y = min(y, edge_at(x) - ly / 2 - rng.uniform(12, 30))
        roof = b.material(f"{tag}-roof{b.next_instance}", Material(_jitter(_pick(_ROOF_RGB, rng), rng), 0.8,
                                                                   0.0, 0.25, 1.5))
        wall_h = rng.uniform(3, 6)
        xv, yv = place(x, y)
        clearings.append((x, y, lx / 2 + WOOD_CLEARING_M, ly / 2 + WOOD_CLEARING_M))
        b.add(f"{tag}-house{b.next_instance}", "house", OBSTACLE,
              [(_box(lx, ly, wall_h, 0, 0, height), wall), (_gable(lx + 0.6, ly + 0.6, rng.uniform(2, 4),
                                                                height + wall_h), roof)],
              xv, yv, along_deg)
        if rng.random() < 0.6:
            car_mat = b.material(f"{tag}-car{b.next_instance}",
                                 Material(_jitter(_pick(_CAR_RGB, rng), rng, 0.1), 0.3, 0.5, 0.05))
            xv, yv = place(x + lx / 2 + 3.0, road_y + rng.uniform(6, 12))
            b.add(f"{tag}-car{b.next_instance}", "car", OBSTACLE,
                  [(_box(4.5, 1.8, 0.8, 0, 0, height + 0.2), car_mat),
                   (_box(2.4, 1.6, 0.6, -0.2, 0, height + 1.0), car_mat)], xv, yv, along_deg + 90.0)
        x += lx + rng.uniform(8, 30)
    if wooded_share > 0 and rng.random() < wooded_share:
        _add_woods(b, tag, place, edge_at, along_deg, length_m, height, bark, road_y, clearings)
    return edge_at


#: share of shores whose land is wooded behind the waterline, not a lawn with a few clumps:
#: most of the lake-shore photos show canopy over most of the land, houses in clearings
WOODED_SHARE = 0.65
#: metres of open ground kept round a house and either side of the road's centre in a wood
WOOD_CLEARING_M = 2.0
WOOD_ROAD_CLEARING_M = 5.0
#: woods reach this far either way along the shore from the point nearest the vessel: a
#: camera at 150 m, offset by 10 %, sees about 120 m either way
WOOD_HALF_LENGTH_M = 130.0
#: a crown's footprint is about 2.24 r^2 (mean of 200 crowns of :func:`_crown_lobes`, 10-90 %:
#: 1.96-2.52), not pi (1.15 r)^2: its lobes reach 1.15 r only here and there
CROWN_AREA_PER_R2 = 2.24


def _add_tree(b: _Builder, tag: str, at_v: tuple[float, float], along_deg: float, radius_m: float,
              ground_z: float, bark: str) -> None:
    """A tree at ``at_v`` (vessel frame): a trunk and a lumpy crown of radius ``radius_m``,
    1.5-3 radii tall, in one of the greens of sunlit deciduous canopy in the lake-shore
    photos (linear RGB) or a darker conifer's, leaf clusters a metre or less across."""
    rng = b.rng
    crown_rgb = _pick([(0.04, 0.1, 0.02), (0.07, 0.14, 0.03), (0.1, 0.16, 0.04), (0.05, 0.08, 0.03),
                       (0.12, 0.13, 0.05), (0.1, 0.22, 0.04), (0.14, 0.25, 0.06)], rng)
    crown = b.material(f"{tag}-crown{b.next_instance}", Material(_jitter(crown_rgb, rng), 0.95,
                                                                 0.0, 0.5, 2.5))
    tall = float(rng.uniform(1.5, 3.0)) * radius_m
    b.add(f"{tag}-tree{b.next_instance}", "tree", OBSTACLE,
          [(_cylinder(0.25 + 0.03 * radius_m, tall - radius_m, 0, 0, ground_z, 6), bark)]
          + [(lobe, crown) for lobe in _crown_lobes(radius_m, ground_z + tall - 0.5 * radius_m, rng)],
          at_v[0], at_v[1], along_deg)


def _add_woods(b: _Builder, tag: str, place, edge_at, along_deg: float, length_m: float,
               ground_z: float, bark: str, road_y: float,
               clearings: list[tuple[float, float, float, float]]) -> None:
    """Canopy over the land from 3 m behind the waterline to 35-75 m back, within
    :data:`WOOD_HALF_LENGTH_M` of the shore's middle (no camera of the family sees farther
    along it): trees of 3.5-8 m crown radius at uniform random places, their crowns' areas
    adding up to 0.6-1.4 times the band's (they overlap, so 45-75 % of it is covered, less
    the clearings), none with its trunk within a house's clearing or on the road, and none
    beyond the builder's ``view_reach_m`` (the view, not the scene, is what the woods fill).
    Local coordinates of the shore (x along it, y toward the water)."""
    rng = b.rng
    depth_m = float(rng.uniform(35.0, 75.0))
    cover = float(rng.uniform(0.6, 1.4))
    half_m = min(WOOD_HALF_LENGTH_M, length_m / 2 - 5)
    r_low, r_high = 3.5, 8.0
    # E[r^2] of r ~ U(r_low, r_high), times a crown's footprint per r^2
    mean_crown_m2 = CROWN_AREA_PER_R2 * (r_high ** 3 - r_low ** 3) / (3 * (r_high - r_low))
    for _ in range(int(cover * 2 * half_m * depth_m / mean_crown_m2)):
        x = float(rng.uniform(-half_m, half_m))
        y = edge_at(x) - float(rng.uniform(3.0, depth_m))
        radius = float(rng.uniform(r_low, r_high))
        at_v = place(x, y)
        if abs(y - road_y) < WOOD_ROAD_CLEARING_M or any(
                abs(x - cx) < hx and abs(y - cy) < hy for cx, cy, hx, hy in clearings):
            continue
        if b.view_reach_m is not None and math.hypot(*at_v) > b.view_reach_m + radius:
            continue        # never in view: its draws are made all the same
        _add_tree(b, tag, at_v, along_deg, radius, ground_z, bark)


#: dock and pontoon decking: weathered and stained wood
_WOOD_RGB = [(0.28, 0.2, 0.12), (0.35, 0.3, 0.24), (0.2, 0.14, 0.08), (0.45, 0.42, 0.38)]
#: white and grey composite boards, which many of the lake-shore photos' docks are
_COMPOSITE_RGB = [(0.72, 0.72, 0.7), (0.58, 0.58, 0.56)]
#: drive-on jet-ski ports: white, light grey, black and blue plastic floats
_PORT_RGB = [(0.8, 0.8, 0.78), (0.55, 0.56, 0.58), (0.06, 0.06, 0.07), (0.08, 0.16, 0.4)]
_PORT_P = np.array([0.5, 0.25, 0.15, 0.1])
#: a port's deck above the water, and the height of its two keel rails on it
PORT_DECK_Z_M = 0.18
PORT_RAIL_HEIGHT_M = 0.12


def add_jetski_port(b: _Builder, x_v: float, y_v: float, rel_heading_deg: float, tag: str,
                    with_jetski: bool):
    """A drive-on jet-ski port (a floating plastic cradle, ``obstacle``) centred at
    ``(x_v, y_v)``, its long axis along ``rel_heading_deg``: a slab 3.3-3.8 m by 1.9-2.3 m,
    pointed at its +x end (toward the dock), with two keel rails on top; with a jet ski
    (``ship``) resting on the rails when ``with_jetski``. Returns the objects made."""
    rng = b.rng
    length, width = rng.uniform(3.3, 3.8), rng.uniform(1.9, 2.3)
    plastic = b.material(f"{tag}-port", Material(_jitter(_pick(_PORT_RGB, rng, _PORT_P), rng, 0.08),
                                                 0.45, 0.0, 0.05, 1.0))
    half_l, half_w = length / 2, width / 2
    outline = np.array([(-half_l, -half_w), (half_l - 0.6, -half_w), (half_l, -0.35),
                        (half_l, 0.35), (half_l - 0.6, half_w), (-half_l, half_w)])
    parts = [(_prism(outline, -0.12, PORT_DECK_Z_M), plastic)]
    parts += [(_box(length * 0.7, 0.25, PORT_RAIL_HEIGHT_M, -0.1 * length, side * (half_w - 0.3),
                    PORT_DECK_Z_M), plastic) for side in (-1, 1)]
    made = [b.add(f"{tag}-port", "port", OBSTACLE, parts, x_v, y_v, rel_heading_deg)]
    if with_jetski:
        jetski = add_leisure_boat(b, x_v, y_v, rel_heading_deg, length * 0.88, "jetski")
        # out of the water, its hull resting on the rails (above every part of the port)
        lift_m = PORT_DECK_Z_M + PORT_RAIL_HEIGHT_M - min(
            float(np.asarray(part.mesh.vertices)[:, 2].min()) for part in jetski.parts)
        for part in jetski.parts:
            part.mesh.apply_translation((0.0, 0.0, lift_m))
        made.append(jetski)
    return made


def add_private_dock(b: _Builder, start_v: tuple[float, float], out_deg: float, length_m: float,
                     tag: str) -> list:
    """A dock from the shore at ``start_v`` out along ``out_deg`` (from the bow, clockwise;
    wood or white and grey composite boards): a walkway, a T or L head, a boat lift beside it
    (a frame of posts and rails, a canopy on most) with a boat in it or not, and opposite it
    one or two drive-on jet-ski ports (most with a jet ski on) or a boat or jet ski tied
    alongside."""
    rng = b.rng
    wood = _planks(b, tag, _WOOD_RGB + _COMPOSITE_RGB)
    width = rng.uniform(1.2, 2.4)
    deck_z = rng.uniform(0.3, 0.9)
    parts = [(_box(length_m, width, 0.25, length_m / 2, 0.0, deck_z), wood)]
    head = str(rng.choice(["T", "L", "none"], p=[0.4, 0.35, 0.25]))
    if head != "none":
        head_len = rng.uniform(6, 14)
        y_off = 0.0 if head == "T" else rng.choice([-1, 1]) * (head_len / 2 - width / 2)
        parts.append((_box(width * 1.5, head_len, 0.25, length_m - width * 0.75, y_off, deck_z), wood))
    dock = b.add(f"{tag}-dock", "dock", OBSTACLE, parts, *start_v, out_deg)
    placed = [dock]
    side = float(rng.choice([-1, 1]))

    def beside(x_local: float, y_local: float) -> tuple[float, float]:
        return _local_to_vessel(start_v, out_deg, x_local, y_local)

    if rng.random() < 0.75 and length_m > 11:
        # a lift: four posts, two rails, usually a canopy; 3.2-3.8 m wide, 7-9 m long
        lift_w, lift_l = rng.uniform(3.2, 3.8), rng.uniform(7.0, 9.0)
        x_c = rng.uniform(lift_l / 2 + 1, length_m - lift_l / 2)
        y_c = side * (width / 2 + 0.4 + lift_w / 2)
        steel = b.material(f"{tag}-lift", Material(_grey((0.5, 0.5, 0.52), rng, 0.2), 0.4, 0.7, 0.05))
        posts = [(_cylinder(0.12, 4.2, sx * lift_l / 2, sy * lift_w / 2, -1.0, 6), steel)
                 for sx in (-1, 1) for sy in (-1, 1)]
        rails = [(_box(lift_l, 0.2, 0.2, 0, sy * lift_w / 2, 2.9), steel) for sy in (-1, 1)]
        lift_parts = posts + rails
        if rng.random() < 0.75:
            canopy_rgb = _pick(_COVER_RGB + [(0.75, 0.75, 0.72)] * 2, rng)
            canopy = b.material(f"{tag}-canopy", Material(_jitter(canopy_rgb, rng), 0.85, 0.0, 0.15, 1.5))
            lift_parts.append((_gable(lift_l + 0.6, lift_w + 0.5, rng.uniform(0.5, 1.0), 3.2), canopy))
        xv, yv = beside(x_c, y_c)
        placed.append(b.add(f"{tag}-lift", "lift", OBSTACLE, lift_parts, xv, yv, out_deg))
        if rng.random() < 0.6:
            placed.append(add_leisure_boat(b, xv, yv, out_deg + float(rng.choice([0.0, 180.0])),
                                           lift_l * rng.uniform(0.7, 0.85)))
    if rng.random() < 0.3 and length_m > 8:
        # one or two drive-on jet-ski ports along the dock, across it, opposite the lift
        n_ports = int(rng.integers(1, 3))
        x_c = rng.uniform(3.0, max(3.1, length_m - 2.6 * n_ports))
        y_c = -side * (width / 2 + 0.25 + 1.8)
        for k in range(n_ports):
            xv, yv = beside(x_c + 2.6 * k, y_c)
            made = add_jetski_port(b, xv, yv, out_deg - side * 90.0, f"{tag}-{k}",
                                   with_jetski=bool(rng.random() < 0.65))
            if _overlaps_others(made, b, margin_m=0.1):
                del b.objects[-len(made):]
            else:
                placed += made
    elif rng.random() < 0.6 and length_m > 6:
        boat_l = rng.uniform(4.0, 8.0)
        kind = "jetski" if rng.random() < 0.25 else None
        x_c = rng.uniform(boat_l / 2, max(boat_l / 2 + 0.1, length_m - boat_l / 2))
        y_c = -side * (width / 2 + 0.5 + boat_l * 0.2)
        xv, yv = beside(x_c, y_c)
        boat = add_leisure_boat(b, xv, yv, out_deg + float(rng.choice([0.0, 180.0])), boat_l, kind)
        if _overlaps_others([boat], b, margin_m=0.2):
            b.objects.remove(boat)
        else:
            placed.append(boat)
    return placed


def build_lakeshore(b: _Builder, hull: Polygon, hull_xy: np.ndarray, side: int, gap_m: float) -> None:
    """The vessel of interest off a residential shore on ``side`` (+1 starboard): docks reach
    toward it; one that would come nearer than ``gap_m`` to its hull is shortened."""
    rng = b.rng
    skew = float(rng.uniform(-15, 15))
    reach = float(rng.uniform(8, 25))             # how far the docks reach out from the shore
    half_beam = float(hull_xy[:, 1].max() if side > 0 else -hull_xy[:, 1].min())
    shore_y = side * (half_beam + gap_m + reach)
    along = skew if side > 0 else 180.0 + skew    # water on the left of the shore's direction
    edge_at = add_shore(b, (0.0, shore_y), along, "shore", wooded_share=WOODED_SHARE)
    limit = gap_m + 0.05
    vessel_fp = b.objects[0].footprint()          # W, as every footprint
    out_deg = along - 90.0                        # from the shore toward the water
    x = float(rng.uniform(-120, -90))
    while x < 120:
        start = _local_to_vessel((0.0, shore_y), along, x, edge_at(x) - 1.5)
        length = reach * rng.uniform(0.5, 1.0) + 1.5 if abs(x) > 30 else reach + 1.5 + rng.uniform(0, 6)
        for _ in range(3):                        # shorten the dock until it keeps the gap
            if length <= 4.0:
                break
            n_before = len(b.objects)
            add_private_dock(b, start, out_deg, length, f"dock{b.next_instance}")
            new = b.objects[n_before:]
            nearest = min(o.footprint().distance(vessel_fp) for o in new)
            if nearest >= limit and not _overlaps_others(new, b):
                break
            del b.objects[n_before:]
            if nearest >= limit:                  # it hit another dock: leave the place empty
                break
            length -= limit - nearest + 0.5
        x += float(rng.uniform(18, 45))
